//! The resume-state loader on arbitrary bytes, restoring into a small FetchReach agent (hidden 16,
//! 2 layers: seeds are resume files of `pgser-train --hidden 16 --layers 2` on FetchReach).
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;
use pgser::agent::{Agent, AgentConfig, Normalizer};
use pgser::task::Task;

fuzz_target!(|data: &[u8]| {
    let p = common::file("a.ckpt.resume", data);
    let task = Task::known("FetchReach").unwrap();
    let cfg = AgentConfig { hidden: 16, layers: 2, ..AgentConfig::default() };
    let device = pgser::agent::Backend::Cpu.device().unwrap();
    let mut agent = Agent::new(cfg, task.clone(), Normalizer::identity(&task, 5.0), 0, device);
    let _ = pgser::agent::checkpoint::load_resume(&mut agent, &p);
});

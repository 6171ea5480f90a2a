//! The checkpoint loader (safetensors header, tensor shapes, metadata, the tensor digest) on
//! arbitrary bytes. Seeds: any `.ckpt` pgser-train writes.
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = common::file("a.ckpt", data);
    let device = pgser::agent::Backend::Cpu.device().unwrap();
    if let Ok((agent, _)) = pgser::agent::checkpoint::load(&p, device) {
        // What it accepts acts: the networks have the shapes the task says.
        let t = agent.task.clone();
        let a = agent.act(&vec![0.0; t.obs_dim], &vec![0.0; t.goal_dim], 1);
        assert_eq!(a.len(), t.act_dim);
    }
});

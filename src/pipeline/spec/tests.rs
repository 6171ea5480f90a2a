//! Pipeline files read into specs: keys, defaults, refusals, and what reaches the plan.

use super::*;
use crate::sampler::priority::PriorityKind;

const MIN: &str = r#"
    name = "t"
    task = "FetchReach"
    out = "../out/t"
    [data]
    pickles = ["../data/a.pkl", "b.pkl"]
    episodes = [5, 10]
    [train]
    batch_size = 64
    lr = 0.001
    [agents]
    seeds = [0, 1]
    updates = 300
    priority_alpha = 0.5
"#;

#[test]
fn layers_apply_in_order_and_paths_resolve_against_the_file() {
    let p = Pipeline::parse(MIN, Path::new("pipes/t.toml")).unwrap();
    assert_eq!(p.out, PathBuf::from("out/t"));
    match &p.data {
        Data::Pickles { inputs, episodes, drop } => {
            assert_eq!(inputs, &[PathBuf::from("data/a.pkl"), PathBuf::from("pipes/b.pkl")]);
            assert_eq!(episodes.as_deref(), Some(&[5, 10][..]));
            assert!(drop.is_empty());
        }
        d => panic!("{d:?}"),
    }
    let c = p.agent_config(Algo::Td3, &p.agents.variants[1], 1).unwrap();
    assert_eq!((c.batch_size, c.updates, c.seed), (64, 300, 1));
    assert_eq!(c.agent.lr, Some(0.001));
    assert_eq!(c.agent.algo, Algo::Td3);
    assert_eq!(c.sampler.swap, crate::sampler::Swap::Random);
    assert_eq!(c.priority.priority_alpha, 0.5);
    assert_eq!(c.priority.priority, PriorityKind::Rank, "a file that names no priority gets the default");
    let q = p.pretrain_config().unwrap();
    assert_eq!((q.agent.algo, q.sampler.swap, q.updates), (Algo::Td3bc, crate::sampler::Swap::Random, 500_000));
    let variants: Vec<_> = p.agents.variants.iter().map(|a| (a.name.as_str(), a.variant)).collect();
    assert_eq!(variants, [("baseline", Variant::Baseline), ("swap", Variant::Swap), ("mem", Variant::Mem)]);
    assert_eq!(p.q_checkpoint, None);
}

/// Named arms: `-mem` twice with other priority settings, in the order `variants` lists
/// them, each cell with its arm's settings over `[agents]`'s, and `[train]`'s priority (as
/// the committed pipelines pin the paper's q) under an arm that names none; and a Q given by path.
#[test]
fn named_arms_and_a_given_q() {
    let text = MIN
        .replace("lr = 0.001", "lr = 0.001\npriority = \"q\"")
        .replace("seeds = [0, 1]", "seeds = [0, 1]\nvariants = [\"mem\", \"mem_a3\", \"rank\"]")
        + "[agents.arms.mem_a3]\nvariant = \"mem\"\npriority_alpha = 3.0\n\
           [agents.arms.rank]\nvariant = \"mem\"\npriority = \"rank\"\n\
           [pretrain]\ncheckpoint = \"../q/q.ckpt\"\nupdates = 10\n";
    let p = Pipeline::parse(&text, Path::new("pipes/t.toml")).unwrap();
    let names: Vec<_> = p.agents.variants.iter().map(|a| (a.name.as_str(), a.variant)).collect();
    assert_eq!(names, [("mem", Variant::Mem), ("mem_a3", Variant::Mem), ("rank", Variant::Mem)]);
    let cfg = |i: usize| p.agent_config(Algo::Td3bc, &p.agents.variants[i], 0).unwrap();
    assert_eq!((cfg(0).priority.priority_alpha, cfg(0).priority.priority), (0.5, PriorityKind::Q));
    assert_eq!((cfg(1).priority.priority_alpha, cfg(1).priority.priority), (3.0, PriorityKind::Q));
    assert_eq!((cfg(2).priority.priority_alpha, cfg(2).priority.priority), (0.5, PriorityKind::Rank));
    assert_eq!(cfg(1).sampler.swap, crate::sampler::Swap::None);
    assert_eq!(p.q_checkpoint.as_deref(), Some(Path::new("q/q.ckpt")));
    assert_eq!(p.pretrain_config().unwrap().updates, 10, "checkpoint is not a training setting");

    let err = |text: &str| format!("{:#}", Pipeline::parse(text, Path::new("t.toml")).unwrap_err());
    let arm = |body: &str| {
        MIN.replace("seeds = [0, 1]", "seeds = [0, 1]\nvariants = [\"mem\", \"a\"]") + "[agents.arms.a]\n" + body
    };
    assert!(err(&arm("priority_alpha = 3.0")).contains("[agents.arms.a]: give its variant"));
    assert!(err(&arm("variant = \"best\"")).contains("[agents.arms.a] variant"));
    assert!(err(&arm("variant = \"mem\"\npriority_alpha = \"x\"")).contains("[agents.arms.a]"));
    assert!(err(&arm("variant = \"mem\"\nprioirty = \"rank\"")).contains("prioirty"));
    assert!(err(&arm("variant = \"mem\"\nseed = 3")).contains("[agents.arms.a] seed: set by the grid"));
    let unlisted = MIN.to_string() + "[agents.arms.b]\nvariant = \"mem\"\n";
    assert!(err(&unlisted).contains("[agents.arms.b] is not listed"), "{}", err(&unlisted));
    let named_mem = MIN.replace("seeds = [0, 1]", "seeds = [0, 1]\nvariants = [\"mem\"]")
        + "[agents.arms.mem]\nvariant = \"mem\"\n";
    assert!(err(&named_mem).contains("cannot take a variant's name"));
    let bad_q = MIN.to_string() + "[pretrain]\ncheckpoint = 3\n";
    assert!(err(&bad_q).contains("[pretrain] checkpoint = 3: must be a path"));
}

#[test]
fn mistakes_are_named() {
    let bad = MIN.replace("batch_size = 64", "batch_sise = 64");
    let e = format!("{:#}", Pipeline::parse(&bad, Path::new("t.toml")).unwrap_err());
    assert!(e.contains("batch_sise"), "{e}");
    let bad = MIN.replace("batch_size = 64", "batch_size = \"big\"");
    let e = format!("{:#}", Pipeline::parse(&bad, Path::new("t.toml")).unwrap_err());
    assert!(e.contains("wrong type"), "{e}");
    let bad = MIN.replace("FetchReach", "FetchNothing");
    assert!(format!("{:#}", Pipeline::parse(&bad, Path::new("t.toml")).unwrap_err()).contains("FetchNothing"));
    let bad = MIN.replace("episodes = [5, 10]", "episodes = [5]");
    assert!(format!("{:#}", Pipeline::parse(&bad, Path::new("t.toml")).unwrap_err()).contains("2 pickles"));
    let bad = MIN.replace("seeds = [0, 1]", "seeds = [0, 1]\nvariants = [\"best\"]");
    assert!(format!("{:#}", Pipeline::parse(&bad, Path::new("t.toml")).unwrap_err()).contains("variants"));
}

/// `arithmetic` reaches the pre-training and the agents and their steps' keys (so changing it
/// retrains them); without it the keys are what they were before the setting existed.
#[test]
fn arithmetic_reaches_training_and_its_keys() {
    use crate::agent::Arithmetic;
    let keys = |text: &str| {
        let p = Pipeline::parse(text, Path::new("pipes/t.toml")).unwrap();
        let steps = crate::pipeline::plan(&p).unwrap();
        let train: Vec<_> =
            steps.into_iter().filter(|s| s.name == "pretrain" || s.name.starts_with("agent ")).collect();
        (p, train.into_iter().map(|s| s.params).collect::<Vec<_>>())
    };
    let (p, native) = keys(MIN);
    assert_eq!(p.pretrain_config().unwrap().agent.arithmetic, Arithmetic::Native);
    assert!(native.iter().all(|k| !k.to_string().contains("arithmetic")), "a native run's key names no arithmetic");
    let (p, portable) = keys(&MIN.replace("lr = 0.001", "lr = 0.001\narithmetic = \"portable\""));
    assert_eq!(p.pretrain_config().unwrap().agent.arithmetic, Arithmetic::Portable);
    assert_eq!(p.agent_config(Algo::Td3bc, &p.agents.variants[0], 0).unwrap().agent.arithmetic, Arithmetic::Portable);
    assert_eq!(native.len(), portable.len());
    assert!(native.iter().zip(&portable).all(|(a, b)| a != b), "every training step's key changes");
    let bad = MIN.replace("lr = 0.001", "lr = 0.001\narithmetic = \"exact\"");
    let e = format!("{:#}", Pipeline::parse(&bad, Path::new("t.toml")).unwrap_err());
    assert!(e.contains("wrong type") && e.contains("exact"), "{e}");
}

/// `[data] drop` reaches convert and its step's key, so that changing it reruns convert; a
/// pipeline without it keeps the key it had. The data a pipeline makes has nothing to drop.
#[test]
fn drop_reaches_convert_and_its_key() {
    let convert = |text: &str| {
        let p = Pipeline::parse(text, Path::new("pipes/t.toml")).unwrap();
        let steps = crate::pipeline::plan(&p).unwrap();
        let step = steps.into_iter().find(|s| s.name == "convert").unwrap();
        let crate::pipeline::Action::Convert(o) = step.action else { panic!("convert converts") };
        (step.params, o.drop)
    };
    let (params, drop) = convert(MIN);
    assert_eq!(params, serde_json::json!({"task": "FetchReach", "episodes": [5, 10]}));
    assert!(drop.is_empty());
    let (params, drop) = convert(&MIN.replace("episodes = [5, 10]", "episodes = [5, 10]\ndrop = [\"meta\", \"1\"]"));
    assert_eq!(drop, ["meta", "1"]);
    assert_eq!(params, serde_json::json!({"task": "FetchReach", "episodes": [5, 10], "drop": ["meta", "1"]}));

    let simulated =
        MIN.replace("pickles = [\"../data/a.pkl\", \"b.pkl\"]", "expert = 2\nrandom = 2\ndrop = [\"meta\"]");
    let e = format!("{:#}", Pipeline::parse(&simulated, Path::new("t.toml")).unwrap_err());
    assert!(e.contains("[data] drop leaves keys of the given `pickles` out"), "{e}");
    let e = format!(
        "{:#}",
        Pipeline::parse(&MIN.replace("episodes = [5, 10]", "drop = \"meta\""), Path::new("t.toml")).unwrap_err()
    );
    assert!(e.contains("drop"), "{e}");
}

/// The fuzzer's input (tests/fixtures/fuzz/pipeline/): a grid file with a seed listed twice, which
/// planned two agents under one name. Each kind of repeat is now a one-line error.
#[test]
fn a_grid_cell_listed_twice_is_named() {
    let fuzzed = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/fuzz/pipeline/seed-listed-twice.toml");
    let e = format!("{:#}", Pipeline::load(&fuzzed).unwrap_err());
    assert!(e.contains("seed-listed-twice.toml") && e.contains("seeds: 1 is listed twice"), "{e}");
    assert!(!e.contains('\n'), "{e}");
    let err = |text: &str| format!("{:#}", Pipeline::parse(text, Path::new("t.toml")).unwrap_err());
    assert!(err(&MIN.replace("seeds = [0, 1]", "seeds = [0, 1, 0]")).contains("seeds: 0 is listed twice"));
    let twice = MIN.replace("seeds = [0, 1]", "seeds = [0, 1]\nvariants = [\"swap\", \"mem\", \"swap\"]");
    assert!(err(&twice).contains("variants: \"swap\" is listed twice"), "{}", err(&twice));
    let twice = MIN.replace("seeds = [0, 1]", "seeds = [0, 1]\nalgos = [\"td3\", \"td3\"]");
    assert!(err(&twice).contains("algos: \"td3\" is listed twice"), "{}", err(&twice));
    assert_eq!(repeated(&[3, 1, 4, 1, 5]), Some(&1));
    assert_eq!(repeated::<u8>(&[]), None);
}

#[test]
fn a_trained_expert_and_its_online_settings() {
    let base = r#"
        name = "h"
        task = "HandManipulateBlockRotateZ"
        out = "../out/h"
        [data]
        expert = 5
        random = 5
        expert_checkpoint = "../data/experts/h.ckpt"
        [agents]
    "#;
    let p = Pipeline::parse(&format!("{base}\n[expert]\nepochs = 7\ncycles = 3"), Path::new("pipes/h.toml")).unwrap();
    match &p.data {
        Data::Collect { checkpoint, .. } => {
            assert_eq!(checkpoint.as_deref(), Some(Path::new("data/experts/h.ckpt")))
        }
        d => panic!("{d:?}"),
    }
    assert_eq!((p.expert.task.as_str(), p.expert.epochs, p.expert.cycles), ("HandManipulateBlockRotateZ", 7, 3));
    assert_eq!(p.expert.batch_size, 1024, "MRN's defaults for the rest");
    let err = |text: &str| format!("{:#}", Pipeline::parse(text, Path::new("h.toml")).unwrap_err());
    assert!(err(&format!("{base}\n[expert]\nepoch = 7")).contains("\"epoch\""));
    assert!(err(&format!("{base}\n[expert]\ntask = \"FetchPush\"")).contains("the task is the pipeline's"));
    assert!(err(&format!("{base}\n[expert]\nepochs = \"many\"")).contains("wrong type"));
    let scripted = base.replace("expert_checkpoint = \"../data/experts/h.ckpt\"", "");
    assert!(err(&format!("{scripted}\n[expert]\nepochs = 7")).contains("without expert_checkpoint"));
}

#[test]
fn normalize_is_lexical() {
    assert_eq!(normalize(Path::new("pipelines/../out/./demo")), PathBuf::from("out/demo"));
    assert_eq!(normalize(Path::new("../x/../y")), PathBuf::from("../y"));
    assert_eq!(normalize(Path::new("/a/../b")), PathBuf::from("/b"));
}

#[test]
fn a_memory_budget_reads_as_a_size_or_bytes_and_is_left_out_when_unset() {
    let table = |t: &str| -> toml::Table { toml::from_str(t).unwrap() };
    let c = train_config(&[&table(r#"memory_budget = "8GB""#)]).unwrap();
    assert_eq!(c.memory_budget, Some(8_000_000_000));
    let c = train_config(&[&table("memory_budget = 1048576")]).unwrap();
    assert_eq!(c.memory_budget, Some(1 << 20));
    let e = train_config(&[&table(r#"memory_budget = "8XB""#)]).unwrap_err().to_string();
    assert!(e.contains("unknown unit"), "{e}");
    // Unset, the settings' JSON (checkpoints, content keys) is what it was before the key existed.
    let c = train_config(&[]).unwrap();
    assert!(serde_json::to_value(&c).unwrap().get("memory_budget").is_none());
}

/// `[data] table`: an existing table, resolved against the file like every path, used as β with
/// no convert step and its path in the score step's key; combined with any other data key it is
/// refused, naming each.
#[test]
fn a_table_is_beta_as_it_is_and_refuses_the_other_data_keys() {
    let text = MIN
        .replace("pickles = [\"../data/a.pkl\", \"b.pkl\"]\n    episodes = [5, 10]", "table = \"../t/beta.parquet\"");
    let p = Pipeline::parse(&text, Path::new("pipes/t.toml")).unwrap();
    match &p.data {
        Data::Table { path } => assert_eq!(path, Path::new("t/beta.parquet")),
        d => panic!("{d:?}"),
    }
    let steps = crate::pipeline::plan(&p).unwrap();
    assert!(steps.iter().all(|s| s.name != "convert" && !s.name.starts_with("collect")));
    let pretrain = steps.iter().find(|s| s.name == "pretrain").unwrap();
    assert_eq!(pretrain.inputs, [PathBuf::from("t/beta.parquet")]);
    let score = steps.iter().find(|s| s.name == "score").unwrap();
    assert_eq!(score.params["table"], "t/beta.parquet");
    assert_eq!(score.outputs, [PathBuf::from("out/t/scored.parquet")]);

    let err = |text: &str| format!("{:#}", Pipeline::parse(text, Path::new("t.toml")).unwrap_err());
    let both = MIN.replace("episodes = [5, 10]", "episodes = [5, 10]\ntable = \"beta.parquet\"");
    let e = err(&both);
    assert!(e.contains("[data] table") && e.contains("`pickles`, `episodes`"), "{e}");
    let seeded = text.replace("table =", "seed = 3\nnoise = 0.1\ntable =");
    assert!(err(&seeded).contains("`seed`, `noise`"), "{}", err(&seeded));
    let oracle = text.replace("table =", "oracle = 5\ntable =");
    assert!(err(&oracle).contains("`oracle`"), "{}", err(&oracle));
    assert!(err(&text.replace("../t/beta.parquet", "")).contains("[data] table = \"\""));
}

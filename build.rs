//! Give binaries and tests an rpath to MuJoCo's shared library, so `target/release/pgser-*`
//! run with no LD_LIBRARY_PATH. The folder comes from `.cargo/config.toml` (`make deps`).
//! Also bakes in where `make deps` puts the gymnasium-robotics assets, so the Fetch
//! environments (`pgser::env`) find their XML with no environment variable either, and where
//! it puts numpy's ziggurat tables.

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    let dir = std::env::var("MUJOCO_DYNAMIC_LINK_DIR")
        .expect("MUJOCO_DYNAMIC_LINK_DIR is unset: run `make deps` (see .cargo/config.toml)");
    if !std::path::Path::new(&dir).join("libmujoco.so").exists() {
        panic!("{dir}/libmujoco.so is missing: run `make deps` to fetch MuJoCo 3.17.0 from its wheel");
    }
    println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");

    // Not checked here: a build without assets is fine; `pgser::env` names the path at run time.
    let root = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let assets = std::path::Path::new(&root).join(".deps/gymnasium_robotics/assets");
    println!("cargo::rustc-env=PGSER_FETCH_ASSETS={}", assets.display());
    // numpy's ziggurat tables for the hand tasks' normals (`pgser::nprandom::ziggurat`), same rule.
    let zig = std::path::Path::new(&root).join(".deps/numpy_ziggurat.bin");
    println!("cargo::rustc-env=PGSER_ZIGGURAT={}", zig.display());
    // Where `make` unpacks NVRTC (the nvidia-cuda-nvrtc wheel), for the CUDA engine's kernel
    // compiler when the library is not on the loader's path (src/agent/cuda/nvrtc.rs).
    let nvrtc = std::path::Path::new(&root).join(".deps/nvrtc/nvidia/cu13/lib");
    println!("cargo::rustc-env=PGSER_NVRTC_LIBS={}", nvrtc.display());

    // The CUDA engine's kernels as C++ for the host (src/agent/cuda/shim.h): its tests run the
    // whole engine on this CPU. No FMA contraction: the kernels must round as the CPU engine does.
    for f in ["kernels.cu", "shim.h", "shim.cpp"] {
        println!("cargo::rerun-if-changed=src/agent/cuda/{f}");
    }
    cc::Build::new()
        .cpp(true)
        .file("src/agent/cuda/shim.cpp")
        .flag("-std=c++17")
        .flag("-ffp-contract=off")
        .flag("-fno-fast-math")
        .opt_level(2)
        .warnings(true)
        .compile("pgser_cuda_shim");
}

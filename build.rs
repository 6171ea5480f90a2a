//! Give binaries and tests an rpath to MuJoCo's shared library, so `target/release/pgser-*`
//! run with no LD_LIBRARY_PATH. The folder comes from `.cargo/config.toml` (`make deps`).
//! Also bakes in where `make deps` puts the gymnasium-robotics assets, so the Fetch
//! environments (`pgser::env`) find their XML with no environment variable either, and where
//! it puts numpy's ziggurat tables.
//!
//! A clone where `make deps` has not run lacks MuJoCo and CMake: that is said first, in one line
//! with what to run. cargo runs this script and those of mujoco-rs and hdf5-metno-src side by side
//! (none waits for another), so theirs may fail first; scripts/cmake, the CMake of hdf5-metno-src's
//! build, says the same line.

use std::path::Path;

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    println!("cargo::rerun-if-env-changed=CMAKE");
    let root = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let root = Path::new(&root);
    let dir = std::env::var("MUJOCO_DYNAMIC_LINK_DIR").unwrap_or_default();
    let mut missing = Vec::new();
    if !Path::new(&dir).join("libmujoco.so").exists() {
        missing.push(format!("MuJoCo 3.17.0 ({dir}/libmujoco.so)"));
    }
    // The `hdf5` feature builds HDF5 with CMake: .cargo/config.toml's scripts/cmake runs the one
    // in .deps; a CMAKE of the user's own is taken as it is.
    let cmake = std::env::var("CMAKE").unwrap_or_default();
    let deps_cmake = root.join(".deps/cmake/bin/cmake");
    if std::env::var_os("CARGO_FEATURE_HDF5").is_some()
        && Path::new(&cmake) == root.join("scripts/cmake")
        && !deps_cmake.exists()
    {
        missing.push(format!("CMake ({})", deps_cmake.display()));
    }
    if !missing.is_empty() {
        println!(
            "cargo::error={} missing: run `make deps` in {} (or set MUJOCO_DYNAMIC_LINK_DIR and CMAKE to your own)",
            missing.join(" and "),
            root.display()
        );
        return;
    }
    println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");

    // Not checked here: a build without assets is fine; `pgser::env` names the path at run time.
    let assets = root.join(".deps/gymnasium_robotics/assets");
    println!("cargo::rustc-env=PGSER_FETCH_ASSETS={}", assets.display());
    // numpy's ziggurat tables for the hand tasks' normals (`pgser::nprandom::ziggurat`), same rule.
    let zig = root.join(".deps/numpy_ziggurat.bin");
    println!("cargo::rustc-env=PGSER_ZIGGURAT={}", zig.display());
    // Where `make` unpacks NVRTC (the nvidia-cuda-nvrtc wheel), for the CUDA engine's kernel
    // compiler when the library is not on the loader's path (src/agent/cuda/nvrtc.rs).
    let nvrtc = root.join(".deps/nvrtc/nvidia/cu13/lib");
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

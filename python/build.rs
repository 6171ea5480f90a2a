//! The module links MuJoCo's shared library like pgser's binaries do (see the root build.rs):
//! an rpath to the folder `make deps` fills, so `import pgser` needs no LD_LIBRARY_PATH. Link
//! arguments of a dependency's build script do not reach a dependent, hence this second one.

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    let dir = std::env::var("MUJOCO_DYNAMIC_LINK_DIR")
        .expect("MUJOCO_DYNAMIC_LINK_DIR is unset: run `make deps` (see .cargo/config.toml)");
    println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
}

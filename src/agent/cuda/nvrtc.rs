//! `kernels.cu` compiled by NVRTC, and where the CUDA libraries are found.
//!
//! The engine compiles its kernels when it starts, for the GPU it finds (`sm_XY` from the
//! device's compute capability), into a cubin: a cubin needs no JIT, so a driver older than the
//! NVRTC that compiled it still loads it, where newer PTX would not load (NVRTC 13.5's PTX 9.5 on
//! a driver-580 machine). `make test` compiles the same source here, without a GPU, for sm_90
//! (H100/H200), with ptxas' report: a compile error or a register spill fails the tests.
//!
//! **The libraries.** cudarc opens `libnvrtc.so.13`, `libcublas.so.13` (and the driver's
//! `libcuda.so.1`) by name. They come with a CUDA toolkit, or from PyPI's `nvidia-cuda-nvrtc` and
//! `nvidia-cublas` wheels (`<site-packages>/nvidia/cu13/lib`), which is how `make` installs NVRTC
//! here (`.deps/nvrtc`) and how JAX and PyTorch users already have them. Where they are not on the
//! loader's path, `preload` loads them by absolute path first (a library loaded once is found by
//! its name afterwards), from `PGSER_CUDA_LIBS`, then `.deps/nvrtc` of this build, then the
//! `nvidia` package of `python3`.

use std::ffi::{CString, c_char};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use cudarc::nvrtc::{result, sys};

/// The kernels' source, compiled into the binary.
pub const SOURCE: &str = include_str!("kernels.cu");

/// Every kernel the engine launches (and `shim.cpp`'s table holds).
pub const KERNELS: &[&str] = &[
    "pgser_gather",
    "pgser_inputs",
    "pgser_bias_act",
    "pgser_target_action",
    "pgser_td_target",
    "pgser_critic_grad",
    "pgser_critic_sums",
    "pgser_bias_grad",
    "pgser_relu_mask",
    "pgser_policy_input",
    "pgser_pi_sums",
    "pgser_fill",
    "pgser_lambdas",
    "pgser_actor_grad",
    "pgser_actor_sums",
    "pgser_adam",
    "pgser_min_q",
    "pgser_tanh",
];

/// The folder of `make`'s NVRTC (the nvidia-cuda-nvrtc wheel, unpacked), baked in by build.rs.
const BUILD_LIBS: &str = env!("PGSER_NVRTC_LIBS");

/// What NVRTC made: a cubin (or PTX, for a `compute_XY` target) and its log (ptxas' register and
/// spill report with `verbose`).
#[derive(Debug)]
pub struct Compiled {
    pub image: Vec<u8>,
    pub log: String,
}

/// The folders to look for CUDA's libraries in, in order (see the module comment).
fn lib_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var_os("PGSER_CUDA_LIBS").map(PathBuf::from).into_iter().collect();
    dirs.push(PathBuf::from(BUILD_LIBS));
    // `nvidia` is a namespace package: each wheel (nvrtc, cublas, …) may sit in its own folder.
    let probe = std::process::Command::new("python3")
        .args(["-c", "import nvidia, os\nfor p in nvidia.__path__: print(os.path.join(p, 'cu13', 'lib'))"])
        .stderr(std::process::Stdio::null())
        .output();
    if let Some(out) = probe.ok().filter(|o| o.status.success()) {
        dirs.extend(String::from_utf8_lossy(&out.stdout).lines().map(|l| PathBuf::from(l.trim())));
    }
    // A CUDA toolkit's usual homes.
    dirs.extend(["/usr/local/cuda/lib64", "/usr/local/cuda/targets/x86_64-linux/lib"].map(PathBuf::from));
    dirs
}

/// Loads each of `names` (in order) by absolute path from the first folder that has them all,
/// unless the last (the one cudarc opens) already loads by name. Returns the folder used, if any.
pub fn preload(names: &[&str]) -> Option<PathBuf> {
    let loads = |path: &str| {
        let c = CString::new(path).expect("no NUL in a path");
        // SAFETY: dlopen with a valid C string; the handle is kept open on purpose (the library
        // must stay loaded for cudarc to find it by name).
        !unsafe { libc::dlopen(c.as_ptr(), libc::RTLD_NOW | libc::RTLD_GLOBAL) }.is_null()
    };
    if loads(names.last().expect("names")) {
        return None;
    }
    lib_dirs().into_iter().find(|dir| {
        names.iter().all(|n| dir.join(n).exists()) && names.iter().all(|n| loads(&dir.join(n).to_string_lossy()))
    })
}

/// The CUDA libraries this process has mapped (cuBLAS, cuBLASLt, NVRTC, the driver), by path,
/// once each: what the engine prints when it starts. cudarc opens a library by trying names in
/// its own order, the unversioned `libcublas.so` and the CUDA 12 names among them, so where two
/// CUDA versions sit on the loader's path only this says which one was taken.
pub fn loaded_libraries() -> Vec<String> {
    std::fs::read_to_string("/proc/self/maps").map(|m| cuda_libraries_in(&m)).unwrap_or_default()
}

/// `loaded_libraries` over the text of a `/proc/PID/maps`.
pub fn cuda_libraries_in(maps: &str) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for path in maps.lines().filter_map(|l| l.split_whitespace().nth(5)) {
        let file = path.rsplit('/').next().unwrap_or(path);
        let cuda = ["libcublas.so", "libcublasLt.so", "libnvrtc.so", "libnvrtc-builtins.so", "libcuda.so"]
            .iter()
            .any(|lib| file.starts_with(lib));
        if cuda && !out.iter().any(|p| p == path) {
            out.push(path.to_string());
        }
    }
    out
}

/// NVRTC's libraries (the builtins first: libnvrtc opens it by name).
pub fn preload_nvrtc() -> Option<PathBuf> {
    preload(&["libnvrtc-builtins.so.13.0", "libnvrtc.so.13"])
}

/// Whether NVRTC can be loaded (after `preload_nvrtc`).
pub fn available() -> bool {
    preload_nvrtc();
    // SAFETY: only tries to open the library by its candidate names.
    unsafe { sys::is_culib_present() }
}

/// NVRTC's version, (major, minor).
pub fn version() -> Result<(i32, i32)> {
    if !available() {
        bail!("{}", missing());
    }
    let (mut major, mut minor) = (0, 0);
    // SAFETY: two out-pointers to live integers.
    unsafe { sys::nvrtcVersion(&mut major, &mut minor) }.result().context("nvrtcVersion")?;
    Ok((major, minor))
}

fn missing() -> String {
    format!(
        "NVRTC (libnvrtc.so.13) not found: install the nvidia-cuda-nvrtc wheel (pip install nvidia-cuda-nvrtc==13.0.88) or a CUDA 13 toolkit, or set PGSER_CUDA_LIBS to the folder holding libnvrtc.so.13 (searched: {})",
        lib_dirs().iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(", ")
    )
}

/// Compiles `SOURCE` for `arch` (`sm_90`: a cubin; `compute_90`: PTX). Floats as the CPU engine
/// rounds them: no FMA contraction, IEEE division and square root, denormals kept.
pub fn compile(arch: &str, verbose: bool) -> Result<Compiled> {
    compile_source(SOURCE, arch, verbose)
}

/// Compiles `source` as `compile` compiles the kernels; a compile error returns NVRTC's log.
pub fn compile_source(source: &str, arch: &str, verbose: bool) -> Result<Compiled> {
    if !available() {
        bail!("{}", missing());
    }
    let src = CString::new(source).context("a NUL in the source")?;
    let prog = result::create_program(&src, Some(c"kernels.cu")).context("nvrtcCreateProgram")?;
    let mut opts = vec![
        format!("--gpu-architecture={arch}"),
        "--fmad=false".to_string(),
        "--prec-div=true".to_string(),
        "--prec-sqrt=true".to_string(),
        "--ftz=false".to_string(),
        "--std=c++17".to_string(),
    ];
    if verbose {
        opts.push("--ptxas-options=-v".to_string());
    }
    // SAFETY: `prog` was created above and is destroyed once, at the end.
    let outcome = unsafe { result::compile_program(prog, &opts) };
    // SAFETY: as above.
    let log = unsafe { result::get_program_log(prog) }.map(|l| c_chars(&l)).unwrap_or_default();
    let image = outcome.map_err(anyhow::Error::from).and_then(|()| {
        if arch.starts_with("sm_") {
            let mut size = 0usize;
            // SAFETY: as above; the buffer is sized by NVRTC's own answer.
            unsafe { sys::nvrtcGetCUBINSize(prog, &mut size) }.result()?;
            let mut buf = vec![0u8; size];
            unsafe { sys::nvrtcGetCUBIN(prog, buf.as_mut_ptr().cast::<c_char>()) }.result()?;
            Ok(buf)
        } else {
            // SAFETY: as above.
            let ptx = unsafe { result::get_ptx(prog) }?;
            Ok(c_chars(&ptx).into_bytes())
        }
    });
    // SAFETY: as above.
    unsafe { result::destroy_program(prog) }.ok();
    match image {
        Ok(image) => Ok(Compiled { image, log }),
        Err(e) => bail!("kernels.cu does not compile for {arch} ({e}):\n{log}"),
    }
}

fn c_chars(v: &[c_char]) -> String {
    let bytes: Vec<u8> = v.iter().map(|&c| c as u8).take_while(|&b| b != 0).collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

/// From ptxas' `-v` report: each kernel's registers and spill stores/loads, as
/// (kernel, registers, spill bytes stored, spill bytes loaded).
pub fn ptxas_report(log: &str) -> Vec<(String, u32, u32, u32)> {
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    let mut spills = (0, 0);
    for line in log.lines() {
        if let Some(rest) = line.split("Compiling entry function '").nth(1) {
            current = rest.split('\'').next().map(str::to_string);
        } else if line.contains("bytes spill stores") {
            let num = |tag: &str| {
                line.split(tag)
                    .next()
                    .and_then(|s| s.split_whitespace().last())
                    .and_then(|s| s.parse().ok())
                    .unwrap_or(0)
            };
            spills = (num(" bytes spill stores"), num(" bytes spill loads"));
        } else if line.contains("Used ") && line.contains("registers") {
            let regs = line
                .split("Used ")
                .nth(1)
                .and_then(|s| s.split_whitespace().next())
                .and_then(|s| s.parse().ok())
                .unwrap_or(0);
            if let Some(k) = current.take() {
                out.push((k, regs, spills.0, spills.1));
            }
        }
    }
    out
}

/// What `pgser-train cuda-kernels` reports: the compiler and each kernel's resources.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Report {
    pub nvrtc: String,
    pub arch: String,
    /// The image's size: a cubin for `sm_XY`, PTX for `compute_XY`.
    pub cubin_bytes: usize,
    /// (kernel, registers, spill bytes stored, spill bytes loaded).
    pub kernels: Vec<(String, u32, u32, u32)>,
}

/// Compiles the kernels for `arch` with ptxas' report; the cubin, if asked for, is written to
/// `cubin` (for a machine without NVRTC: `PGSER_CUDA_CUBIN`).
pub fn report(arch: &str, cubin: Option<&Path>) -> Result<Report> {
    let (major, minor) = version()?;
    let compiled = compile(arch, true)?;
    if let Some(path) = cubin {
        let file = crate::output::AtomicFile::create(path)?;
        std::io::Write::write_all(&mut file.handle()?, &compiled.image)
            .with_context(|| format!("{}: writing the cubin", path.display()))?;
        file.commit()?;
    }
    Ok(Report {
        nvrtc: format!("{major}.{minor}"),
        arch: arch.to_string(),
        cubin_bytes: compiled.image.len(),
        kernels: ptxas_report(&compiled.log),
    })
}

/// The cubin the engine loads: `PGSER_CUDA_CUBIN` when set (built elsewhere, for this GPU),
/// else compiled here for `arch`.
pub fn cubin_for(arch: &str) -> Result<Vec<u8>> {
    if let Some(path) = std::env::var_os("PGSER_CUDA_CUBIN") {
        let path = Path::new(&path);
        return std::fs::read(path).with_context(|| format!("PGSER_CUDA_CUBIN={}", path.display()));
    }
    Ok(compile(arch, false)?.image)
}

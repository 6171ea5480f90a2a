//! The engine's device: an NVIDIA GPU through cudarc (the driver API, cuBLAS and NVRTC, all
//! loaded at run time, so a build needs no CUDA). One stream; every call is queued on it.

use std::mem::ManuallyDrop;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use cudarc::cublas::{CudaBlas, sys as blas};
use cudarc::driver::{CudaContext, CudaFunction, CudaGraph, CudaStream, LaunchConfig, PushKernelArg, result, sys};
use cudarc::nvrtc::Ptx;

use super::{Arg, Gemm, Gpu, Ptr, nvrtc};
use crate::agent::engine::Precision;

/// cuBLAS's workspace, fixed: under graph capture cuBLAS must not allocate its own.
const BLAS_WORKSPACE: usize = 32 << 20;

/// One pinned host buffer of `stage`, and the event that marks its last copy done.
struct Pinned {
    ptr: *mut f32,
    len: usize,
    copied: sys::CUevent,
}

pub struct CudaGpu {
    ctx: Arc<CudaContext>,
    stream: Arc<CudaStream>,
    /// Destroyed by hand in `drop`, before the workspace it was given, and not at all after a
    /// device fault: cudarc's own drop unwraps the destroy call, and a second panic while the
    /// first unwinds aborts the process before the fault is reported.
    blas: ManuallyDrop<CudaBlas>,
    functions: Vec<(&'static str, CudaFunction)>,
    allocs: Vec<Ptr>,
    /// `stage`'s two pinned buffers, used in turn.
    pinned: [Option<Pinned>; 2],
    turn: usize,
    graphs: Vec<CudaGraph>,
    /// The device's name and compute capability, for logs.
    pub name: String,
}

// SAFETY: cudarc's handles are thread-safe to move; the engine uses this value from one thread
// at a time (behind its Mutex).
unsafe impl Send for CudaGpu {}

impl Drop for CudaGpu {
    fn drop(&mut self) {
        // A sticky error (an illegal address in a kernel) makes every later call fail: then the
        // cuBLAS handle is left as it is (the process is about to report the fault and exit).
        let healthy = self.stream.synchronize().is_ok();
        self.graphs.clear();
        if healthy {
            // SAFETY: dropped once, here, while its workspace (in `allocs`) is still allocated.
            unsafe { ManuallyDrop::drop(&mut self.blas) };
        }
        for p in self.pinned.iter_mut().filter_map(Option::take) {
            // SAFETY: allocated by malloc_host with its event in `stage`, freed once, stream idle.
            unsafe {
                let _ = result::event::destroy(p.copied);
                let _ = result::free_host(p.ptr.cast());
            }
        }
        for &p in &self.allocs {
            // SAFETY: allocated by malloc_sync below, freed once, after the stream is idle.
            let _ = unsafe { result::free_sync(p) };
        }
    }
}

/// Whether the NVIDIA driver's library loads at all (without it cudarc's calls panic).
pub fn driver_present() -> bool {
    // SAFETY: only tries to open the library by its candidate names.
    unsafe { cudarc::driver::sys::is_culib_present() }
}

/// CUDA device `ordinal` with the engine's kernels loaded, or a one-line reason why not.
pub fn open(ordinal: usize, precision: Precision) -> Result<CudaGpu> {
    if !driver_present() {
        bail!(
            "--device cuda: no NVIDIA driver here (libcuda.so.1 does not load): use --device cpu, or run on a machine with an NVIDIA GPU and its driver"
        );
    }
    nvrtc::preload(&["libcublasLt.so.13", "libcublas.so.13"]);
    // SAFETY: only tries to open the library by its candidate names.
    if !unsafe { blas::is_culib_present() } {
        bail!(
            "--device cuda: cuBLAS (libcublas.so.13) not found: pip install nvidia-cublas (CUDA 13), or set PGSER_CUDA_LIBS to the folder holding it"
        );
    }
    let ctx = CudaContext::new(ordinal).context("--device cuda: opening the GPU")?;
    // The engine tracks its own order (one stream); cudarc's events would only add work, and
    // get in the way of graph capture.
    // SAFETY: no CudaSlice is shared between streams here.
    unsafe { ctx.disable_event_tracking() };
    let (major, minor) = ctx.compute_capability()?;
    let name = format!("{} (sm_{major}{minor})", ctx.name()?);
    let cubin = nvrtc::cubin_for(&format!("sm_{major}{minor}")).context("--device cuda: compiling the kernels")?;
    let module = ctx.load_module(Ptx::from_binary(cubin)).context("--device cuda: loading the kernels")?;
    let functions = nvrtc::KERNELS
        .iter()
        .map(|&k| Ok((k, module.load_function(k).with_context(|| format!("kernel {k}"))?)))
        .collect::<Result<Vec<_>>>()?;
    let stream = ctx.new_stream()?;
    let blas = ManuallyDrop::new(CudaBlas::new(stream.clone()).context("--device cuda: cuBLAS")?);
    let mut version = 0;
    // SAFETY: a live handle and an out-pointer to a live integer.
    unsafe { blas::cublasGetVersion_v2(*blas.handle(), &mut version) }.result().context("cublasGetVersion")?;
    let libraries = nvrtc::loaded_libraries();
    // The build binds CUDA 13's API (CUDARC_CUDA_VERSION); cuBLAS 12 would take the same calls
    // and compute with another library's kernels, or fail later in a way that names nothing.
    if version / 10_000 != 13 {
        drop(ManuallyDrop::into_inner(blas));
        bail!(
            "--device cuda: the cuBLAS loaded is version {version}, not 13 ({}): put the nvidia-cublas wheel's nvidia/cu13/lib folder first on LD_LIBRARY_PATH, or set PGSER_CUDA_LIBS to it",
            libraries.iter().filter(|l| l.contains("cublas")).cloned().collect::<Vec<_>>().join(", ")
        );
    }
    // Once per process, as burn's backends name their adapter: which GPU, precision and kernels.
    static LOGGED: std::sync::Once = std::sync::Once::new();
    LOGGED.call_once(|| {
        let kernels = match std::env::var_os("PGSER_CUDA_CUBIN") {
            Some(p) => format!("kernels from {}", std::path::Path::new(&p).display()),
            None => format!(
                "kernels compiled by NVRTC {}",
                nvrtc::version().map_or("?".into(), |(a, b)| format!("{a}.{b}"))
            ),
        };
        let device = if precision == Precision::Tf32 { "cuda-tf32" } else { "cuda" };
        eprintln!(
            "--device {device}: running on {name}, {precision:?} products, {kernels}, cuBLAS {version}; libraries: {}",
            libraries.join(", ")
        );
    });
    let mode = match precision {
        Precision::F32 => blas::cublasMath_t::CUBLAS_DEFAULT_MATH,
        Precision::Tf32 => blas::cublasMath_t::CUBLAS_TF32_TENSOR_OP_MATH,
    };
    // SAFETY: a live handle.
    unsafe { blas::cublasSetMathMode(*blas.handle(), mode) }.result().context("cublasSetMathMode")?;
    let mut gpu = CudaGpu {
        ctx,
        stream,
        blas,
        functions,
        allocs: Vec::new(),
        pinned: [None, None],
        turn: 0,
        graphs: Vec::new(),
        name,
    };
    let workspace = gpu.alloc(BLAS_WORKSPACE)?;
    // SAFETY: a live handle and a device buffer of that size, owned by `gpu` as long as the handle.
    unsafe { blas::cublasSetWorkspace_v2(*gpu.blas.handle(), workspace as *mut _, BLAS_WORKSPACE) }
        .result()
        .context("cublasSetWorkspace")?;
    Ok(gpu)
}

impl Gpu for CudaGpu {
    fn alloc(&mut self, bytes: usize) -> Result<Ptr> {
        // Raw driver calls act on the calling thread's current context: every method binds it
        // (the trainer, an evaluation and the scorer may call from different threads).
        self.ctx.bind_to_thread()?;
        // SAFETY: a plain allocation, freed on drop. Zeroed on the engine's stream, which orders
        // the fill before every later use: `cuMemsetD8` would run on the legacy default stream,
        // which a non-blocking stream does not wait for.
        let p = unsafe { result::malloc_sync(bytes.max(1).next_multiple_of(256)) }.context("cuMemAlloc")?;
        unsafe { result::memset_d8_async(p, 0, bytes.max(1), self.stream.cu_stream()) }.context("cuMemsetD8Async")?;
        self.allocs.push(p);
        Ok(p)
    }

    fn free_memory(&mut self) -> Result<usize> {
        self.ctx.bind_to_thread()?;
        Ok(result::mem_get_info().context("cuMemGetInfo")?.0)
    }

    fn free(&mut self, ptr: Ptr) -> Result<()> {
        self.ctx.bind_to_thread()?;
        let i = self.allocs.iter().position(|&p| p == ptr).context("free of memory this device did not allocate")?;
        self.allocs.swap_remove(i);
        self.stream.synchronize()?;
        // SAFETY: allocated by malloc_sync, no longer in `allocs`, and the stream is idle.
        unsafe { result::free_sync(ptr) }.context("cuMemFree")?;
        Ok(())
    }

    fn upload(&mut self, dst: Ptr, src: &[u8]) -> Result<()> {
        self.ctx.bind_to_thread()?;
        // SAFETY: `dst` is one of our allocations, sized by the engine for `src`; a synchronous
        // copy from pageable memory returns once `src` may be reused.
        unsafe { result::memcpy_htod_async(dst, src, self.stream.cu_stream()) }.context("upload")?;
        Ok(())
    }

    fn download(&mut self, src: Ptr, dst: &mut [u8]) -> Result<()> {
        self.ctx.bind_to_thread()?;
        // SAFETY: as upload; the stream is synchronized before `dst` is read.
        unsafe { result::memcpy_dtoh_async(dst, src, self.stream.cu_stream()) }.context("download")?;
        self.stream.synchronize().context("download")?;
        Ok(())
    }

    fn launch(&mut self, name: &'static str, items: usize, args: &[Arg]) -> Result<()> {
        self.ctx.bind_to_thread()?;
        let f = &self.functions.iter().find(|(k, _)| *k == name).with_context(|| format!("no kernel {name}"))?.1;
        let block = 256u32;
        let grid = items.div_ceil(block as usize).clamp(1, 65_535) as u32;
        let mut b = self.stream.launch_builder(f);
        for a in args {
            match a {
                Arg::P(v) => b.arg(v),
                Arg::I(v) => b.arg(v),
                Arg::L(v) => b.arg(v),
                Arg::F(v) => b.arg(v),
            };
        }
        let cfg = LaunchConfig { grid_dim: (grid, 1, 1), block_dim: (block, 1, 1), shared_mem_bytes: 0 };
        // SAFETY: the arguments are typed as the kernel declares them (the engine's contract).
        unsafe { b.launch(cfg) }.with_context(|| format!("launching {name}"))?;
        Ok(())
    }

    fn stage(&mut self, dst: Ptr, len: usize, fill: &mut dyn FnMut(&mut [f32])) -> Result<()> {
        self.ctx.bind_to_thread()?;
        let slot = &mut self.pinned[self.turn];
        self.turn = 1 - self.turn;
        if slot.as_ref().is_some_and(|p| p.len < len) {
            let old = slot.take().expect("checked");
            // SAFETY: its last copy is waited for before the buffer goes.
            unsafe {
                result::event::synchronize(old.copied)?;
                result::event::destroy(old.copied)?;
                result::free_host(old.ptr.cast())?;
            }
        }
        if slot.is_none() {
            // SAFETY: page-locked memory of `len` floats, freed on drop; an event to fence it.
            let ptr = unsafe { result::malloc_host(4 * len, 0) }.context("cuMemAllocHost")?.cast::<f32>();
            let copied = result::event::create(sys::CUevent_flags::CU_EVENT_DISABLE_TIMING)?;
            *slot = Some(Pinned { ptr, len, copied });
        } else {
            // SAFETY: the event was recorded after this buffer's last copy.
            unsafe { result::event::synchronize(slot.as_ref().expect("some").copied) }.context("staging")?;
        }
        let p = slot.as_ref().expect("some");
        // SAFETY: `len` floats of our pinned buffer, whose previous copy has finished.
        let host = unsafe { std::slice::from_raw_parts_mut(p.ptr, len) };
        fill(host);
        unsafe {
            result::memcpy_htod_async(dst, &host[..], self.stream.cu_stream()).context("staging copy")?;
            result::event::record(p.copied, self.stream.cu_stream())?;
        }
        Ok(())
    }

    fn begin_capture(&mut self) -> Result<()> {
        self.ctx.bind_to_thread()?;
        self.stream
            .begin_capture(sys::CUstreamCaptureMode::CU_STREAM_CAPTURE_MODE_THREAD_LOCAL)
            .context("beginning a graph capture")?;
        Ok(())
    }

    fn end_capture(&mut self) -> Result<usize> {
        self.ctx.bind_to_thread()?;
        let graph = self
            .stream
            .end_capture(sys::CUgraphInstantiate_flags(0))
            .context("ending a graph capture")?
            .context("the capture recorded nothing")?;
        self.graphs.push(graph);
        Ok(self.graphs.len() - 1)
    }

    fn replay(&mut self, graph: usize) -> Result<()> {
        self.ctx.bind_to_thread()?;
        self.graphs.get(graph).context("no such graph")?.launch().context("launching a graph")?;
        Ok(())
    }

    /// Row-major C = A·B is column-major Cᵀ = Bᵀ·Aᵀ: cuBLAS gets B first, and a row-major
    /// operand is the column-major transpose of itself with the same leading dimension.
    fn gemm(&mut self, g: &Gemm) -> Result<()> {
        self.ctx.bind_to_thread()?;
        let op = |t: bool| if t { blas::cublasOperation_t::CUBLAS_OP_T } else { blas::cublasOperation_t::CUBLAS_OP_N };
        let (alpha, beta) = (1.0f32, 0.0f32);
        // SAFETY: every operand lies inside the engine's allocations (the host shim checks the
        // same calls); the handle's stream is ours.
        unsafe {
            blas::cublasSgemmStridedBatched(
                *self.blas.handle(),
                op(g.b.trans),
                op(g.a.trans),
                g.n as i32,
                g.m as i32,
                g.k as i32,
                &alpha,
                g.b.ptr as *const f32,
                g.b.ld as i32,
                g.b.stride as i64,
                g.a.ptr as *const f32,
                g.a.ld as i32,
                g.a.stride as i64,
                &beta,
                g.c.ptr as *mut f32,
                g.c.ld as i32,
                g.c.stride as i64,
                g.batch as i32,
            )
        }
        .result()
        .context("cublasSgemmStridedBatched")?;
        Ok(())
    }
}

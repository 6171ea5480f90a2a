//! The engine on the host, for the tests: `kernels.cu` compiled as C++ through `shim.h` (build.rs),
//! each kernel launched by name as `driver.rs` launches it on the GPU, and the CPU engine's own
//! `gemm` calls standing in for cuBLAS (part by part where the CPU engine multiplies part by part),
//! so that the engine here computes the CPU engine's bits. Every product's operands are checked
//! to lie inside one allocation, so an engine that addresses past a buffer fails here loudly
//! rather than reading a neighbour on the GPU.

use std::alloc::Layout;
use std::ffi::{CString, c_char, c_void};

use anyhow::{Result, bail};

use super::{Arg, Gemm, Gpu, Mat, Ptr, arg_pointers};
use crate::agent::fused::gemm_raw;

unsafe extern "C" {
    fn pgser_shim_launch(name: *const c_char, grid: u32, block: u32, args: *mut *mut c_void) -> i32;
}

/// A launch or a product, as a graph records it.
#[derive(Clone)]
enum Op {
    Launch(&'static str, usize, Vec<Arg>),
    Gemm(Gemm),
}

/// Host memory posing as a device's; graphs are recorded lists of operations, replayed in order
/// (what a CUDA graph is, less the speed).
pub struct HostGpu {
    allocs: Vec<(Ptr, Layout)>,
    recording: Option<Vec<Op>>,
    graphs: Vec<Vec<Op>>,
    /// The host buffer `stage` fills.
    staging: Vec<f32>,
    /// What `free_memory` answers: 1 TB, unless a test plays a small device.
    pub free_bytes: usize,
    /// Tests play a driver that refuses graphs: `end_capture` fails after recording.
    pub refuse_capture: bool,
    /// Tests play a kernel launch that fails: launching this kernel is an error.
    pub fail_launch: Option<&'static str>,
}

impl Default for HostGpu {
    fn default() -> Self {
        HostGpu {
            allocs: Vec::new(),
            recording: None,
            graphs: Vec::new(),
            staging: Vec::new(),
            free_bytes: 1 << 40,
            refuse_capture: false,
            fail_launch: None,
        }
    }
}

// SAFETY: the allocations are owned by this value alone and only touched through `&mut self`.
unsafe impl Send for HostGpu {}

impl Drop for HostGpu {
    fn drop(&mut self) {
        for &(ptr, layout) in &self.allocs {
            // SAFETY: allocated below with this layout, freed once.
            unsafe { std::alloc::dealloc(ptr as *mut u8, layout) };
        }
    }
}

impl HostGpu {
    /// Whether a capture is under way (a test checks that a failed one was ended).
    pub fn capturing(&self) -> bool {
        self.recording.is_some()
    }

    /// Fails unless `[ptr, ptr + bytes)` lies inside one allocation.
    fn check(&self, ptr: Ptr, bytes: usize, what: &str) -> Result<()> {
        let inside = self.allocs.iter().any(|&(base, l)| ptr >= base && ptr + bytes as u64 <= base + l.size() as u64);
        if !inside {
            bail!("host shim: {what} [{ptr:#x}, +{bytes}) is outside every allocation");
        }
        Ok(())
    }

    /// The bytes an operand of `rows × cols` (as read, after its transpose) spans.
    fn span(m: &Mat, rows: usize, cols: usize) -> usize {
        if rows == 0 || cols == 0 {
            return 0;
        }
        let (rs, cs) = if m.trans { (1, m.ld) } else { (m.ld, 1) };
        4 * ((rows - 1) * rs + (cols - 1) * cs + 1)
    }
}

impl Gpu for HostGpu {
    fn alloc(&mut self, bytes: usize) -> Result<Ptr> {
        let layout = Layout::from_size_align(bytes.max(1), 256)?;
        // SAFETY: a non-zero size.
        let ptr = unsafe { std::alloc::alloc_zeroed(layout) };
        if ptr.is_null() {
            bail!("host shim: out of memory for {bytes} bytes");
        }
        self.allocs.push((ptr as Ptr, layout));
        Ok(ptr as Ptr)
    }

    /// The host's memory stands for the device's; tests set `free` to try a device too small.
    fn free_memory(&mut self) -> Result<usize> {
        Ok(self.free_bytes)
    }

    fn free(&mut self, ptr: Ptr) -> Result<()> {
        let Some(i) = self.allocs.iter().position(|&(p, _)| p == ptr) else {
            bail!("host shim: free of {ptr:#x}, which is no allocation");
        };
        let (p, layout) = self.allocs.swap_remove(i);
        // SAFETY: allocated in `alloc` with this layout, and now forgotten by `allocs`.
        unsafe { std::alloc::dealloc(p as *mut u8, layout) };
        Ok(())
    }

    fn upload(&mut self, dst: Ptr, src: &[u8]) -> Result<()> {
        self.check(dst, src.len(), "upload")?;
        // SAFETY: checked to lie inside one of our allocations, which `src` cannot overlap.
        unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), dst as *mut u8, src.len()) };
        Ok(())
    }

    fn download(&mut self, src: Ptr, dst: &mut [u8]) -> Result<()> {
        self.check(src, dst.len(), "download")?;
        // SAFETY: as upload.
        unsafe { std::ptr::copy_nonoverlapping(src as *const u8, dst.as_mut_ptr(), dst.len()) };
        Ok(())
    }

    fn launch(&mut self, name: &'static str, items: usize, args: &[Arg]) -> Result<()> {
        if self.fail_launch == Some(name) {
            bail!("host shim: launching {name} failed (a test's fault)");
        }
        if let Some(ops) = self.recording.as_mut() {
            ops.push(Op::Launch(name, items, args.to_vec()));
            return Ok(());
        }
        // An odd grid of a few small blocks: every grid-stride loop wraps several times, so an
        // index that assumed one thread per item would show.
        let (block, grid) = (7u32, items.div_ceil(7).clamp(1, 3) as u32);
        let mut ptrs = arg_pointers(args);
        let c = CString::new(name)?;
        // SAFETY: the arguments are typed as the kernel declares them (the engine's contract);
        // `ptrs` points into `args`, alive for the call.
        let rc = unsafe { pgser_shim_launch(c.as_ptr(), grid, block, ptrs.as_mut_ptr()) };
        if rc != 0 {
            bail!("host shim: no kernel named {name}");
        }
        Ok(())
    }

    fn gemm(&mut self, g: &Gemm) -> Result<()> {
        if let Some(ops) = self.recording.as_mut() {
            ops.push(Op::Gemm(*g));
            return Ok(());
        }
        for b in 0..g.batch {
            let item = |m: &Mat| Mat { ptr: m.ptr + 4 * (b * m.stride) as u64, ..*m };
            let (a, bm, c) = (item(&g.a), item(&g.b), item(&g.c));
            self.check(a.ptr, Self::span(&a, g.m, g.k), "gemm A")?;
            self.check(bm.ptr, Self::span(&bm, g.k, g.n), "gemm B")?;
            self.check(c.ptr, Self::span(&c, g.m, g.n), "gemm C")?;
            let p = g.parts.unwrap_or(1);
            assert!(p == 1 || !a.trans, "rows cut into parts must be A's rows");
            for q in 0..p {
                let (start, end) = (g.m * q / p, g.m * (q + 1) / p);
                let a = Mat { ptr: a.ptr + 4 * (start * a.ld) as u64, ..a };
                let c = Mat { ptr: c.ptr + 4 * (start * c.ld) as u64, ..c };
                matmul(end - start, g.n, g.k, &c, &a, &bm);
            }
        }
        Ok(())
    }

    fn stage(&mut self, dst: Ptr, len: usize, fill: &mut dyn FnMut(&mut [f32])) -> Result<()> {
        let mut host = std::mem::take(&mut self.staging);
        host.resize(len, 0.0);
        fill(&mut host);
        // SAFETY: f32 has no padding; `host` outlives the slice.
        let bytes = unsafe { std::slice::from_raw_parts(host.as_ptr().cast::<u8>(), 4 * len) };
        let done = self.upload(dst, bytes);
        self.staging = host;
        done
    }

    fn begin_capture(&mut self) -> Result<()> {
        if self.recording.is_some() {
            bail!("host shim: a capture is already under way");
        }
        self.recording = Some(Vec::new());
        Ok(())
    }

    fn end_capture(&mut self) -> Result<usize> {
        let ops = self.recording.take().ok_or_else(|| anyhow::anyhow!("host shim: no capture under way"))?;
        if self.refuse_capture {
            bail!("host shim: the capture was invalidated (a test's fault)");
        }
        self.graphs.push(ops);
        Ok(self.graphs.len() - 1)
    }

    fn replay(&mut self, graph: usize) -> Result<()> {
        let ops = self.graphs.get(graph).cloned().ok_or_else(|| anyhow::anyhow!("host shim: no graph {graph}"))?;
        for op in &ops {
            match op {
                Op::Launch(name, items, args) => self.launch(name, *items, args)?,
                Op::Gemm(g) => self.gemm(g)?,
            }
        }
        Ok(())
    }
}

/// dst (row stride `c.ld`) = A·B through the CPU engine's own `gemm` call.
fn matmul(m: usize, n: usize, k: usize, c: &Mat, a: &Mat, b: &Mat) {
    let op = |x: &Mat| {
        let (rs, cs) = if x.trans { (1, x.ld) } else { (x.ld, 1) };
        (x.ptr as *const f32, rs, cs)
    };
    // SAFETY: the caller checked every operand against its allocation; C overlaps neither input
    // (the engine never multiplies in place).
    unsafe { gemm_raw(m, n, k, c.ptr as *mut f32, c.ld, op(a), op(b)) };
}

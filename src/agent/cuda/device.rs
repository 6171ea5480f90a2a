//! What the CUDA engine needs of a device (`Gpu`: memory, kernels by name, batched products,
//! staging, graphs), in the two forms it takes: `driver.rs` (a GPU) and `host.rs` (the shim the
//! tests run on). Addresses are plain integers so that one launch sequence drives both.

use std::ffi::c_void;

use anyhow::Result;

/// A device address (a host address on the shim).
pub type Ptr = u64;

/// `ptr` advanced by `elems` elements of 4 bytes (f32).
pub(super) fn at(ptr: Ptr, elems: usize) -> Ptr {
    ptr + 4 * elems as u64
}

/// One operand of a product: a row-major matrix at `ptr` with row stride `ld`, read transposed
/// when `trans`; batch item b's matrix starts `stride` elements after item b − 1's.
#[derive(Debug, Clone, Copy)]
pub struct Mat {
    pub ptr: Ptr,
    pub ld: usize,
    pub trans: bool,
    pub stride: usize,
}

/// C = A·B for each of `batch` items (row-major, `m × n`, inner dimension `k`), C dense with row
/// stride `c.ld`. `parts`: the rows of A and C are a batch of n rows cut into parts, which the
/// shim multiplies part by part as the CPU engine does (so that its bits are the CPU engine's);
/// cuBLAS ignores it.
#[derive(Debug, Clone, Copy)]
pub struct Gemm {
    pub m: usize,
    pub n: usize,
    pub k: usize,
    pub a: Mat,
    pub b: Mat,
    pub c: Mat,
    pub batch: usize,
    pub parts: Option<usize>,
}

/// One kernel argument, typed as the kernel declares it.
#[derive(Debug, Clone, Copy)]
pub enum Arg {
    /// `float*` / `double*` (0: null).
    P(Ptr),
    /// `int`.
    I(i32),
    /// `long long`.
    L(i64),
    /// `float`.
    F(f32),
}

/// What the engine needs of a device: memory, the kernels of `kernels.cu` by name, and batched
/// products. Calls are queued in order on one stream; `download` waits for what came before.
pub trait Gpu: Send {
    /// `bytes` of zeroed device memory, 256-byte aligned, owned by the device until it is dropped.
    fn alloc(&mut self, bytes: usize) -> Result<Ptr>;
    /// Bytes of device memory free now.
    fn free_memory(&mut self) -> Result<usize>;
    fn upload(&mut self, dst: Ptr, src: &[u8]) -> Result<()>;
    fn download(&mut self, src: Ptr, dst: &mut [u8]) -> Result<()>;
    /// Returns memory from `alloc` (after the work queued before has finished with it).
    fn free(&mut self, ptr: Ptr) -> Result<()>;
    /// Runs kernel `name` over `items` independent items (a grid-stride loop: any grid is right).
    fn launch(&mut self, name: &'static str, items: usize, args: &[Arg]) -> Result<()>;
    fn gemm(&mut self, g: &Gemm) -> Result<()>;
    /// Queues a copy of `len` f32 into `dst` from a host buffer that `fill` writes first: on a GPU
    /// one of two pinned buffers, so that filling the next update's batch overlaps the copy and
    /// the work of this one (the call waits only until that buffer's previous copy is done).
    fn stage(&mut self, dst: Ptr, len: usize, fill: &mut dyn FnMut(&mut [f32])) -> Result<()>;
    /// From here until `end_capture`, launches and products are recorded, not run.
    fn begin_capture(&mut self) -> Result<()>;
    /// Ends a capture; returns the recorded graph's id for `replay`.
    fn end_capture(&mut self) -> Result<usize>;
    /// Runs a captured graph: its launches and products, with the arguments they were captured
    /// with (so every buffer a graph names must outlive it, and per-update values come from
    /// device memory: `stage`).
    fn replay(&mut self, graph: usize) -> Result<()>;
}

/// The kernel arguments as CUDA takes them: one pointer to each argument's value.
pub fn arg_pointers(args: &[Arg]) -> Vec<*mut c_void> {
    args.iter()
        .map(|a| match a {
            Arg::P(v) => v as *const u64 as *mut c_void,
            Arg::I(v) => v as *const i32 as *mut c_void,
            Arg::L(v) => v as *const i64 as *mut c_void,
            Arg::F(v) => v as *const f32 as *mut c_void,
        })
        .collect()
}

pub(super) fn f32_bytes(v: &[f32]) -> &[u8] {
    // SAFETY: f32 has no padding and every byte pattern is a valid u8.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast(), std::mem::size_of_val(v)) }
}

pub(super) fn download_f32(gpu: &mut dyn Gpu, src: Ptr, len: usize) -> Result<Vec<f32>> {
    let mut out = vec![0.0f32; len];
    // SAFETY: as f32_bytes, mutably; the vector outlives the slice.
    let bytes = unsafe { std::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<u8>(), 4 * len) };
    gpu.download(src, bytes)?;
    Ok(out)
}

/// Device buffers for one call, returned at its end.
pub(super) struct Temp<'a> {
    pub(super) gpu: &'a mut dyn Gpu,
    bufs: Vec<Ptr>,
}

impl<'a> Temp<'a> {
    pub(super) fn new(gpu: &'a mut dyn Gpu) -> Temp<'a> {
        Temp { gpu, bufs: Vec::new() }
    }

    pub(super) fn zeros(&mut self, len: usize) -> Result<Ptr> {
        let p = self.gpu.alloc(4 * len.max(1))?;
        self.bufs.push(p);
        Ok(p)
    }

    pub(super) fn upload(&mut self, v: &[f32]) -> Result<Ptr> {
        let p = self.zeros(v.len())?;
        self.gpu.upload(p, f32_bytes(v))?;
        Ok(p)
    }

    pub(super) fn free(self) -> Result<()> {
        for p in self.bufs {
            self.gpu.free(p)?;
        }
        Ok(())
    }
}

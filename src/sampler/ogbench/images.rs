//! OGBench's pixel batches (`impls/utils/datasets.py`): frame stacks and random crops, made from
//! the table's uint8 images without a float copy.
//!
//! # Frame stacks (`frame_stack` = K)
//! `get_stacked_observations`: the stack at index i is the frames at max(i − j, first) for
//! j = K − 1, …, 0, oldest first, concatenated on the last (channel) axis: an H × W × C image
//! becomes H × W × K·C, pixel by pixel the K frames' C channels in turn. `first` is the first
//! index of i's trajectory as OGBench's compact layout marks trajectories (`initial_locs`, one
//! past each `terminals` = 1): `terminals` is 1 on both of an episode's last two steps there, so
//! step 0 starts every step but the last, and the last step T − 1 starts itself. The one stack
//! that reads step T − 1 is `next_observations` of the last transition (step T − 2), and it is
//! K copies of that last frame. This is OGBench's rule, kept as it is.
//!
//! Every observation key is stacked: observations, next observations and every goal that is an
//! observation. A random goal's frames come from the view (`View::goal_image`, which a pool's
//! reservoir keeps K of), clamped to its episode's first step as above (a random goal is never a
//! last step).
//!
//! # Random crops (`p_aug`)
//! `augment`, after the batch is drawn: with probability `p_aug`, one uniform per batch, the whole
//! batch is cropped (never in `evaluation` batches); each row draws one offset (dy, dx), both
//! uniform on 0..=2·3, shared by every image key of that row. `random_crop` pads by 3 pixels in
//! `edge` mode and cuts H × W at (dy, dx): pixel (y, x) of the crop is pixel
//! (clamp(y + dy − 3, 0, H − 1), clamp(x + dx − 3, 0, W − 1)) of the image, every channel (all
//! K·C of a stack). Offsets (3, 3) give the image back. A key that is not an image (an oracle
//! representation) is not cropped, as OGBench crops only 4-dimensional arrays.

use std::mem::MaybeUninit;

use rayon::prelude::*;

use crate::nprandom::NpRandom;

/// OGBench's padding: offsets are on 0..=2·PAD.
pub(super) const PAD: usize = 3;

/// An image key's geometry: frames of `h` × `w` × `c` bytes, `stack` of them a row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Geometry {
    pub h: usize,
    pub w: usize,
    pub c: usize,
    pub stack: usize,
}

impl Geometry {
    /// Of a table's image shape ([H, W, C]; [H, W] is one channel) and `frame_stack`.
    pub(super) fn of(shape: &[usize], stack: usize) -> Geometry {
        let (h, w) = (shape[0], shape.get(1).copied().unwrap_or(1));
        let c = shape[2..].iter().product::<usize>().max(1);
        Geometry { h, w, c, stack: stack.max(1) }
    }

    /// Bytes of one frame.
    pub(super) fn frame(&self) -> usize {
        self.h * self.w * self.c
    }

    /// Bytes of one row of the key: a stack.
    pub(super) fn row(&self) -> usize {
        self.frame() * self.stack
    }

    /// A row's shape in the batch: [H, W, K·C].
    pub(super) fn shape(&self) -> Vec<usize> {
        vec![self.h, self.w, self.c * self.stack]
    }
}

/// The step frame `back` of a stack at `step` reads (0: `step` itself), by OGBench's compact
/// trajectories: clamped to step 0, but the last step T − 1 starts its own (the module doc).
pub(super) fn stack_step(step: usize, back: usize, t: usize) -> usize {
    if step + 1 == t { step } else { step.saturating_sub(back) }
}

/// Whether this batch is cropped, and each row's (dy, dx): drawn after the batch's rows, only
/// when `p_aug > 0` and the batch is not an evaluation batch, so that other settings draw as
/// they would without.
pub(super) fn crops(rng: &mut NpRandom, p_aug: f64, augment: bool, n: usize) -> Option<Vec<(u8, u8)>> {
    if !augment || p_aug <= 0.0 || rng.random() >= p_aug {
        return None;
    }
    let side = 2 * PAD + 1;
    Some((0..n).map(|_| (rng.below(side) as u8, rng.below(side) as u8)).collect())
}

/// Rows of an image key: for row r, its `stack` frames (`frame(r, j)`, j = 0 oldest) stacked on
/// the channel axis and cropped at `crops[r]` where given. Rows are made in parallel in chunks
/// (the bytes do not depend on the thread count: nothing here draws).
pub(super) fn gather<'a, R: Sync>(
    rows: &[R],
    g: Geometry,
    crops: Option<&[(u8, u8)]>,
    frame: impl Fn(&R, usize) -> &'a [u8] + Sync,
) -> Vec<u8> {
    let row = g.row();
    let total = rows.len() * row;
    let mut out = Vec::with_capacity(total);
    // Huge pages on a key's bytes before they are written: a key of 1024 images is 12.6 MB, a
    // fresh mapping each batch, and with 4 kB pages the kernel's zeroing of its 3,000 pages on
    // first touch was most of a batch's time (perf: `clear_page` under the copies; 60 → 86
    // batches/s in memory). numpy advises its own large arrays the same way.
    if total >= 4 << 20 {
        crate::sampler::pool::advise_huge_pages(out.as_ptr() as usize, total);
    }
    let make = |(i, o): (usize, &mut [MaybeUninit<u8>])| {
        let r = &rows[i];
        let at = crops.map_or((PAD, PAD), |c| (c[i].0 as usize, c[i].1 as usize));
        compose(o, g, at, |j| frame(r, j));
    };
    let spare = &mut out.spare_capacity_mut()[..total];
    if rayon::current_num_threads() > 1 && rows.len() > 1 {
        spare.par_chunks_mut(row).enumerate().with_min_len(16).for_each(make);
    } else {
        spare.chunks_mut(row).enumerate().for_each(make);
    }
    // SAFETY: `compose` wrote every byte of every row (each line of each row, every pixel and
    // every frame of each line), and the rows tile `..total`.
    unsafe { out.set_len(total) };
    out
}

/// Copies `src` into `dst`, of the same length. A batch's image keys are written once, straight
/// into memory that was never zeroed: 12.6 MB a key of 1024 images, a fresh mapping each batch
/// (the batch is handed to numpy), whose huge pages the kernel zeroes anyway.
fn put(dst: &mut [MaybeUninit<u8>], src: &[u8]) {
    assert_eq!(dst.len(), src.len());
    // SAFETY: both are `len` bytes, and a `&mut` slice cannot overlap a shared one.
    unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), dst.as_mut_ptr().cast::<u8>(), src.len()) }
}

/// One row: the frames stacked and shifted by (dy, dx) − PAD with edge padding, into `out`
/// (H × W × K·C bytes), every byte of it written.
fn compose<'a>(out: &mut [MaybeUninit<u8>], g: Geometry, (dy, dx): (usize, usize), frame: impl Fn(usize) -> &'a [u8]) {
    let Geometry { h, w, c, stack } = g;
    let frames: Vec<&[u8]> = (0..stack).map(frame).collect();
    let clamp = |v: usize, n: usize| v.saturating_sub(PAD).min(n - 1);
    if stack == 1 && (dy, dx) == (PAD, PAD) {
        put(out, frames[0]);
        return;
    }
    let line = w * c * stack;
    // Each output pixel's source pixel, as a byte offset in a frame's line.
    let sxs: Vec<usize> = (0..w).map(|x| clamp(x + dx, w) * c).collect();
    let mut lines: Vec<&[u8]> = Vec::with_capacity(stack);
    for (y, o) in out.chunks_exact_mut(line).enumerate() {
        let sy = clamp(y + dy, h);
        if stack == 1 {
            // One frame: the row's middle is one copy, and the padded edges repeat its end pixels.
            let src = &frames[0][sy * w * c..][..w * c];
            let shift = dx as isize - PAD as isize;
            let (lo, hi) = ((-shift).max(0) as usize, (w as isize - shift).min(w as isize) as usize);
            let from = (lo as isize + shift) as usize;
            put(&mut o[lo * c..hi * c], &src[from * c..(from + hi - lo) * c]);
            for x in (0..lo).chain(hi..w) {
                let sx = clamp(x + dx, w);
                put(&mut o[x * c..][..c], &src[sx * c..][..c]);
            }
            continue;
        }
        lines.clear();
        lines.extend(frames.iter().map(|f| &f[sy * w * c..][..w * c]));
        match c {
            3 => interleave::<3>(o, &lines, &sxs),
            1 => interleave::<1>(o, &lines, &sxs),
            _ => {
                for (px, &sx) in o.chunks_exact_mut(c * stack).zip(&sxs) {
                    for (dst, src) in px.chunks_exact_mut(c).zip(&lines) {
                        put(dst, &src[sx..sx + c]);
                    }
                }
            }
        }
    }
}

/// One output line of a stack: pixel x is each frame's pixel at byte `sxs[x]` of its line, `C`
/// channels, in frame order. `C` fixed, so each pixel is one small copy rather than a call
/// (a stack of 3 frames of 64 × 64 × 3 is 12,288 of them an image).
fn interleave<const C: usize>(out: &mut [MaybeUninit<u8>], lines: &[&[u8]], sxs: &[usize]) {
    for (px, &sx) in out.chunks_exact_mut(C * lines.len()).zip(sxs) {
        for (dst, src) in px.chunks_exact_mut(C).zip(lines) {
            let src: &[u8; C] = src[sx..sx + C].try_into().expect("C bytes");
            let dst: &mut [MaybeUninit<u8>; C] = dst.try_into().expect("C bytes");
            for (d, s) in dst.iter_mut().zip(src) {
                d.write(*s);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// OGBench's crop, written as its code does it: pad by 3 in edge mode, then cut.
    fn reference_crop(img: &[u8], [h, w, c]: [usize; 3], (dy, dx): (usize, usize)) -> Vec<u8> {
        let (ph, pw) = (h + 2 * PAD, w + 2 * PAD);
        let mut padded = vec![0u8; ph * pw * c];
        for y in 0..ph {
            for x in 0..pw {
                let (sy, sx) = ((y as isize - 3).clamp(0, h as isize - 1), (x as isize - 3).clamp(0, w as isize - 1));
                for k in 0..c {
                    padded[(y * pw + x) * c + k] = img[(sy as usize * w + sx as usize) * c + k];
                }
            }
        }
        let mut out = Vec::with_capacity(h * w * c);
        for y in 0..h {
            for x in 0..w {
                out.extend_from_slice(&padded[((y + dy) * pw + x + dx) * c..][..c]);
            }
        }
        out
    }

    /// `compose` into a Vec.
    fn composed(g: Geometry, at: (usize, usize), frame: impl Fn(usize) -> Vec<u8>) -> Vec<u8> {
        let frames: Vec<Vec<u8>> = (0..g.stack).map(frame).collect();
        gather(&[()], g, Some(&[(at.0 as u8, at.1 as u8)]), |_, j| &frames[j])
    }

    fn image(seed: u64, n: usize) -> Vec<u8> {
        let mut rng = NpRandom::new(seed);
        (0..n).map(|_| rng.below(256) as u8).collect()
    }

    #[test]
    fn every_crop_offset_is_the_padded_cut_of_ogbench_and_3_3_is_the_image() {
        for (h, w, c) in [(8, 8, 3), (5, 7, 1), (64, 64, 3)] {
            let img = image(h as u64, h * w * c);
            let g = Geometry { h, w, c, stack: 1 };
            for dy in 0..=6 {
                for dx in 0..=6 {
                    let out = composed(g, (dy, dx), |_| img.clone());
                    assert_eq!(out, reference_crop(&img, [h, w, c], (dy, dx)), "{h}x{w}x{c} at ({dy}, {dx})");
                }
            }
            assert_eq!(composed(g, (3, 3), |_| img.clone()), img);
        }
    }

    #[test]
    fn a_stack_is_its_frames_on_the_channel_axis_cropped_alike() {
        let (h, w, c, k) = (6, 5, 3, 3);
        let frames: Vec<Vec<u8>> = (0..k).map(|j| image(10 + j as u64, h * w * c)).collect();
        let g = Geometry { h, w, c, stack: k };
        for at in [(3, 3), (0, 6), (5, 1)] {
            let out = composed(g, at, |j| frames[j].clone());
            // np.concatenate(frames, axis=-1), then the crop of that.
            let mut stacked = Vec::new();
            for p in 0..h * w {
                for f in &frames {
                    stacked.extend_from_slice(&f[p * c..][..c]);
                }
            }
            assert_eq!(out, reference_crop(&stacked, [h, w, c * k], at), "{at:?}");
        }
    }

    #[test]
    fn a_stack_reads_back_to_the_episode_start_and_the_last_step_repeats_itself() {
        let t = 10;
        assert_eq!((0..3).rev().map(|j| stack_step(0, j, t)).collect::<Vec<_>>(), [0, 0, 0]);
        assert_eq!((0..3).rev().map(|j| stack_step(1, j, t)).collect::<Vec<_>>(), [0, 0, 1]);
        assert_eq!((0..3).rev().map(|j| stack_step(5, j, t)).collect::<Vec<_>>(), [3, 4, 5]);
        assert_eq!((0..3).rev().map(|j| stack_step(8, j, t)).collect::<Vec<_>>(), [6, 7, 8]);
        assert_eq!((0..3).rev().map(|j| stack_step(9, j, t)).collect::<Vec<_>>(), [9, 9, 9]);
    }

    #[test]
    fn crops_are_drawn_only_when_asked_and_cover_every_offset_uniformly() {
        let mut rng = NpRandom::new(1);
        assert!(crops(&mut rng, 0.0, true, 10).is_none());
        assert!(crops(&mut rng, 1.0, false, 10).is_none());
        let n = 70_000;
        let c = crops(&mut rng, 1.0, true, n).expect("p_aug = 1 always crops");
        let mut counts = [[0usize; 7]; 2];
        for &(dy, dx) in &c {
            counts[0][dy as usize] += 1;
            counts[1][dx as usize] += 1;
        }
        // Each offset 1/7 of n: 10,000 ± 5σ (σ ≈ 93).
        for axis in counts {
            for k in axis {
                assert!((k as i64 - 10_000).abs() < 470, "{axis:?}");
            }
        }
        // p_aug = 0.5: about half the batches cropped.
        let cropped = (0..4000).filter(|_| crops(&mut rng, 0.5, true, 1).is_some()).count();
        assert!((cropped as i64 - 2000).abs() < 160, "{cropped}");
    }
}

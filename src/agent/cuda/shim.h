// CUDA's built-ins for a C++ compiler, so that kernels.cu runs on the host (`host.rs`).
//
// A kernel launch becomes a loop over the grid's blocks and each block's threads, one plain call
// per CUDA thread, one after another. That is exact for kernels whose threads do not talk to each
// other, which is every kernel of kernels.cu (its header says why): no __syncthreads, no shared
// memory, no atomics or warp shuffles are defined here, so a kernel that uses them fails to
// compile on the host instead of running wrongly. Launches are serialized by the caller.
#pragma once
#include <cmath>
#include <limits>

#define PGSER_SHIM 1
#define __global__
#define __device__
#define __restrict__ __restrict
#define PGSER_INF (std::numeric_limits<float>::infinity())
#define PGSER_UNROLL

struct pgser_dim3 {
    unsigned int x, y, z;
};
// The launching thread's current CUDA thread: thread-local, so that two launches on two host
// threads (cargo runs tests side by side) do not see each other's indices.
extern thread_local pgser_dim3 threadIdx, blockIdx, blockDim, gridDim;


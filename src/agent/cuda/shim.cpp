// The host side of the shim: kernels.cu compiled as C++, and one entry point that launches a
// kernel by name with CUDA's argument convention (an array of pointers to each argument, as
// cuLaunchKernel takes them), so that `host.rs` drives the host exactly as `driver.rs` drives
// the GPU.
#include "shim.h"

#include <cstring>
#include <tuple>
#include <type_traits>
#include <utility>

thread_local pgser_dim3 threadIdx, blockIdx, blockDim, gridDim;

#include "kernels.cu"

namespace {

template <typename... Args, std::size_t... I>
void call(void (*f)(Args...), void** args, std::index_sequence<I...>) {
    f(*static_cast<std::remove_cv_t<std::remove_reference_t<Args>>*>(args[I])...);
}

// Runs every thread of a 1-D grid of `grid` blocks of `block` threads.
template <typename... Args>
void launch(void (*f)(Args...), unsigned grid, unsigned block, void** args) {
    gridDim = {grid, 1, 1};
    blockDim = {block, 1, 1};
    for (unsigned b = 0; b < grid; ++b) {
        blockIdx = {b, 0, 0};
        for (unsigned t = 0; t < block; ++t) {
            threadIdx = {t, 0, 0};
            call(f, args, std::index_sequence_for<Args...>{});
        }
    }
}

struct Entry {
    const char* name;
    void (*run)(unsigned, unsigned, void**);
};

#define PGSER_KERNEL(k) {#k, [](unsigned g, unsigned b, void** a) { launch(k, g, b, a); }}
const Entry KERNELS[] = {
    PGSER_KERNEL(pgser_inputs),      PGSER_KERNEL(pgser_bias_act),     PGSER_KERNEL(pgser_target_action),
    PGSER_KERNEL(pgser_td_target),   PGSER_KERNEL(pgser_critic_grad),  PGSER_KERNEL(pgser_critic_sums),
    PGSER_KERNEL(pgser_bias_grad),   PGSER_KERNEL(pgser_relu_mask),    PGSER_KERNEL(pgser_policy_input),
    PGSER_KERNEL(pgser_pi_sums),     PGSER_KERNEL(pgser_fill),         PGSER_KERNEL(pgser_lambdas),
    PGSER_KERNEL(pgser_actor_grad),  PGSER_KERNEL(pgser_actor_sums),   PGSER_KERNEL(pgser_adam),
    PGSER_KERNEL(pgser_min_q),       PGSER_KERNEL(pgser_tanh),         PGSER_KERNEL(pgser_gather),
};

}  // namespace

// 0 on success, 1 when no kernel has that name.
extern "C" int pgser_shim_launch(const char* name, unsigned grid, unsigned block, void** args) {
    for (const Entry& e : KERNELS) {
        if (std::strcmp(e.name, name) == 0) {
            e.run(grid, block, args);
            return 0;
        }
    }
    return 1;
}

// The elementwise and reduction kernels of the CUDA engine (`mod.rs` has the derivation and the
// order they run in). One source, two compilers:
// - NVRTC compiles it for the GPU (`nvrtc.rs`), with --fmad=false so that no a*b+c is contracted
//   into an FMA the CPU engine does not do;
// - a C++ compiler builds it for the host through `shim.h` (PGSER_SHIM), where each CUDA thread is
//   a plain call, so the whole engine runs and is tested on a machine without a GPU.
//
// Rules that keep both and the CPU engine (`fused/`) equal to the bit where the products are:
// - every kernel is a grid-stride loop over independent items, with no __syncthreads, shared
//   memory or atomics: the shim runs threads one after another, and a float atomic's order would
//   change the bits from run to run;
// - every sum runs in one thread, in the CPU engine's order (a part's rows in order, the parts in
//   order), so it rounds as the CPU engine rounds. The sums are short (a part has ~256 rows);
// - each expression is written in the CPU engine's order of operations.
//
// Layouts (row-major): a stack of `members` networks keeps member m's parameters at m·len of one
// flat buffer (`Shape` order: w0, b0, w1, b1, ...), and its activations for the batch at m·n·d.
// A batch of n rows is cut into p parts, part q being rows [n·q/p, n·(q+1)/p).

#ifndef PGSER_SHIM
#define PGSER_INF __int_as_float(0x7f800000)
// A row loop's loads issued eight at a time (its adds stay in order): one thread walks a part's
// ~256 rows, and one load in flight at a time would leave it waiting on memory.
#define PGSER_UNROLL _Pragma("unroll 8")
#endif

#define PGSER_FOR(i, total)                                                                    \
    for (long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x; i < (long long)(total); \
         i += (long long)blockDim.x * gridDim.x)

// The per-(agent, part) sums the trainer logs and TD3+BC's λ reads, as doubles.
#define PGSER_SUMS 6
#define PGSER_SUM_CRITIC 0 /* Σ_k Σᵢ wᵢ(Q_k − yᵢ)² */
#define PGSER_SUM_Q 1      /* Σᵢ Q₁(sᵢ, aᵢ) */
#define PGSER_SUM_PI_Q 2   /* Σᵢ Q₁(sᵢ, πᵢ) */
#define PGSER_SUM_PI_ABS 3 /* Σᵢ |Q₁(sᵢ, πᵢ)|, summed as a float */
#define PGSER_SUM_BC 4     /* Σᵢⱼ (πᵢⱼ − aᵢⱼ)² */
#define PGSER_SUM_L2 5     /* Σᵢⱼ πᵢⱼ² */

// Adam's per-update constants of one network kind (`consts` slots), written by the host before
// each update so that a captured graph replays with the step it is at.
#define PGSER_STEP_SIZE 0
#define PGSER_BC2_SQRT 1
#define PGSER_KEEP 2
#define PGSER_TAKE 3
#define PGSER_POLYAK 4

// Rust's f32::clamp: NaN stays NaN.
__device__ inline float pgser_clamp(float x, float lo, float hi) {
    if (x < lo) x = lo;
    if (x > hi) x = hi;
    return x;
}

__device__ inline long long pgser_part_start(int n, int p, int q) { return (long long)n * q / p; }

// The batch from the episodes the engine holds (`CudaEngine::hold`), every agent's rows at once:
// row r (of agents·n) is s = obs[io[r]], s' = obs[io[r] + 1], a = act[ia[r]], g = goals[ig[r]],
// with idx = [io; ia; ig], each `rows` long. One thread per value written; a copy, so exact.
extern "C" __global__ void pgser_gather(long long rows, int od, int gd, int act,
                                        const unsigned* __restrict__ idx, const float* __restrict__ obs_t,
                                        const float* __restrict__ goal_t, const float* __restrict__ act_t,
                                        float* __restrict__ obs, float* __restrict__ goal,
                                        float* __restrict__ next_obs, float* __restrict__ action) {
    const int W = 2 * od + gd + act;
    PGSER_FOR(i, rows * W) {
        const long long r = i / W;
        const int c = (int)(i % W);
        if (c < od) {
            obs[r * od + c] = obs_t[(long long)idx[r] * od + c];
        } else if (c < 2 * od) {
            next_obs[r * od + c - od] = obs_t[((long long)idx[r] + 1) * od + c - od];
        } else if (c < 2 * od + gd) {
            const int j = c - 2 * od;
            goal[r * gd + j] = goal_t[(long long)idx[2 * rows + r] * gd + j];
        } else {
            const int j = c - 2 * od - gd;
            action[r * act + j] = act_t[(long long)idx[rows + r] * act + j];
        }
    }
}

// The critics' inputs of every member (members = A·K: agent a's critics k at a·K + k, each with
// its own copy of the agent's rows, so that every critic product is one batch):
// sa = [clip((o − μ)/σ), clip((g − μ)/σ), a] and next_sa = the same of (o', g), its action columns
// left for `pgser_target_action`. `next_obs` and `action` may be null (acting, scoring).
extern "C" __global__ void pgser_inputs(int agents, int K, int n, int od, int gd, int act,
                                        const float* __restrict__ obs, const float* __restrict__ goal,
                                        const float* __restrict__ next_obs,
                                        const float* __restrict__ action, const float* __restrict__ mean,
                                        const float* __restrict__ stdev, const float* __restrict__ clip,
                                        float* __restrict__ sa, float* __restrict__ next_sa) {
    const int sg = od + gd, W = sg + act;
    PGSER_FOR(i, (long long)agents * K * n * W) {
        const int c = (int)(i % W);
        const long long row = i / W;  // member·n + r
        const long long member = row / n;
        const int r = (int)(row % n);
        const long long a = member / K;
        const long long src = a * n + r;  // the agent's row
        const float cl = clip[a];
        if (c < od) {
            const float m = mean[a * sg + c], s = stdev[a * sg + c];
            sa[i] = pgser_clamp((obs[src * od + c] - m) / s, -cl, cl);
            if (next_obs) next_sa[i] = pgser_clamp((next_obs[src * od + c] - m) / s, -cl, cl);
        } else if (c < sg) {
            const float m = mean[a * sg + c], s = stdev[a * sg + c];
            const float v = pgser_clamp((goal[src * gd + c - od] - m) / s, -cl, cl);
            sa[i] = v;
            if (next_obs) next_sa[i] = v;
        } else if (action) {
            sa[i] = action[src * act + c - sg];
        }
    }
}

// out[m, r, :] += b_m, then ReLU below the top layer (Rust's max(0): NaN becomes 0, as fmaxf).
extern "C" __global__ void pgser_bias_act(long long rows, int dout, float* __restrict__ out,
                                          const float* __restrict__ params, long long member_stride,
                                          long long bias_off, int rows_per_member, int relu) {
    PGSER_FOR(i, rows * dout) {
        const long long member = (i / dout) / rows_per_member;
        const float v = out[i] + params[member * member_stride + bias_off + i % dout];
        out[i] = relu ? fmaxf(v, 0.0f) : v;
    }
}

// The target action: tanh of the target actor's output, plus the clipped noise drawn on the host
// (TD3), clipped to ±1; DDPG takes tanh alone. Written into next_sa's action columns of every
// critic copy of the agent's rows. `top` is [A, n, act].
extern "C" __global__ void pgser_target_action(int agents, int K, int n, int act, int W,
                                               const float* __restrict__ top,
                                               const float* __restrict__ noise,
                                               float* __restrict__ next_sa, int ddpg) {
    PGSER_FOR(i, (long long)agents * K * n * act) {
        const int j = (int)(i % act);
        const long long row = i / act;  // member·n + r
        const long long member = row / n;
        const long long src = (member / K) * n + row % n;
        const float a = tanhf(top[src * act + j]);
        next_sa[row * W + (W - act) + j] = ddpg ? a : pgser_clamp(a + noise[src * act + j], -1.0f, 1.0f);
    }
}

// y = clip(r + γ·min_k Q'_k(s', g, ã)); q is the target critics' output [A·K, n].
extern "C" __global__ void pgser_td_target(int agents, int K, int n, const float* __restrict__ q,
                                           const float* __restrict__ reward, float gamma, float lo,
                                           float hi, float* __restrict__ y) {
    PGSER_FOR(i, (long long)agents * n) {
        const long long a = i / n, r = i % n;
        float v = PGSER_INF;
        for (int k = 0; k < K; ++k) v = fminf(v, q[(a * K + k) * n + r]);
        y[i] = pgser_clamp(reward[i] + v * gamma, lo, hi);
    }
}

// ∂L/∂Q_k(i) = 2wᵢ(Q_k(i) − yᵢ)/n (scale = 2/n), for every critic member at once.
extern "C" __global__ void pgser_critic_grad(int agents, int K, int n, const float* __restrict__ q,
                                             const float* __restrict__ y,
                                             const float* __restrict__ weight, float scale,
                                             float* __restrict__ g) {
    PGSER_FOR(i, (long long)agents * K * n) {
        const long long src = (i / n / K) * n + i % n;
        const float d = q[i] - y[src];
        g[i] = scale * weight[src] * d;
    }
}

// Per (agent, part): Σ_k Σᵢ wᵢ(Q_k − yᵢ)² and Σᵢ Q₁, in the CPU engine's order (k, then rows).
extern "C" __global__ void pgser_critic_sums(int agents, int K, int n, int p, const float* __restrict__ q,
                                             const float* __restrict__ y,
                                             const float* __restrict__ weight,
                                             double* __restrict__ sums) {
    PGSER_FOR(i, (long long)agents * p) {
        const long long a = i / p;
        const int part = (int)(i % p);
        const long long start = pgser_part_start(n, p, part), end = pgser_part_start(n, p, part + 1);
        double loss = 0.0, qs = 0.0;
        for (int k = 0; k < K; ++k) {
            PGSER_UNROLL
            for (long long r = start; r < end; ++r) {
                const float qv = q[(a * K + k) * n + r];
                const float w = weight[a * n + r];
                const float d = qv - y[a * n + r];
                loss += (double)(w * d * d);
                if (k == 0) qs += (double)qv;
            }
        }
        sums[i * PGSER_SUMS + PGSER_SUM_CRITIC] = loss;
        sums[i * PGSER_SUMS + PGSER_SUM_Q] = qs;
    }
}

// ∂b of the top layer per (member, part): the column sums of G over the part's rows, in order.
// grad is [members, p, len]; g is [members, n, dout].
extern "C" __global__ void pgser_bias_grad(long long members, int n, int p, int dout,
                                           const float* __restrict__ g, float* __restrict__ grad,
                                           long long len, long long bias_off) {
    PGSER_FOR(i, members * p * dout) {
        const int c = (int)(i % dout);
        const long long mp = i / dout;  // member·p + part
        const long long m = mp / p;
        const int part = (int)(mp % p);
        float s = 0.0f;
        PGSER_UNROLL
        for (long long r = pgser_part_start(n, p, part); r < pgser_part_start(n, p, part + 1); ++r)
            s += g[(m * n + r) * dout + c];
        grad[mp * len + bias_off + c] = s;
    }
}

// The ReLU's mask on t = G·Wᵀ (zero where the layer's output was not positive), and where grad
// is given, that layer's ∂b as the masked column sums per (member, part), in the same pass.
extern "C" __global__ void pgser_relu_mask(long long members, int n, int p, int din, float* __restrict__ t,
                                           const float* __restrict__ below, float* __restrict__ grad,
                                           long long len, long long bias_off) {
    PGSER_FOR(i, members * p * din) {
        const int c = (int)(i % din);
        const long long mp = i / din;
        const long long m = mp / p;
        const int part = (int)(mp % p);
        float s = 0.0f;
        PGSER_UNROLL
        for (long long r = pgser_part_start(n, p, part); r < pgser_part_start(n, p, part + 1); ++r) {
            const long long at = (m * n + r) * din + c;
            const float v = below[at] > 0.0f ? t[at] : 0.0f;
            t[at] = v;
            s += v;
        }
        if (grad) grad[mp * len + bias_off + c] = s;
    }
}

// The critic's input in the actor's loss, [A, n, W]: the agent's (s, g) columns of sa (agent a's
// first critic copy, at member a·K) and π = tanh(u) from the actor's top layer `top` [A, n, act].
extern "C" __global__ void pgser_policy_input(int agents, int K, int n, int W, int act,
                                              const float* __restrict__ sa,
                                              const float* __restrict__ top, float* __restrict__ spi) {
    PGSER_FOR(i, (long long)agents * n * W) {
        const int c = (int)(i % W);
        const long long row = i / W;  // a·n + r
        const long long a = row / n, r = row % n;
        spi[i] = c < W - act ? sa[((a * K) * n + r) * W + c] : tanhf(top[row * act + c - (W - act)]);
    }
}

// Per (agent, part): Σᵢ Q₁(sᵢ, πᵢ) (double) and Σᵢ |Q₁(sᵢ, πᵢ)| (float, as the reference's mean).
extern "C" __global__ void pgser_pi_sums(int agents, int n, int p, const float* __restrict__ q,
                                         double* __restrict__ sums) {
    PGSER_FOR(i, (long long)agents * p) {
        const long long a = i / p;
        const int part = (int)(i % p);
        double qs = 0.0;
        float abs_sum = 0.0f;
        PGSER_UNROLL
        for (long long r = pgser_part_start(n, p, part); r < pgser_part_start(n, p, part + 1); ++r) {
            const float v = q[a * n + r];
            qs += (double)v;
            abs_sum += fabsf(v);
        }
        sums[i * PGSER_SUMS + PGSER_SUM_PI_Q] = qs;
        sums[i * PGSER_SUMS + PGSER_SUM_PI_ABS] = (double)abs_sum;
    }
}

extern "C" __global__ void pgser_fill(long long count, float value, float* __restrict__ x) {
    PGSER_FOR(i, count) x[i] = value;
}

// λ per agent: α / mean|Q₁(s, π)| for TD3+BC (the parts' float sums added in part order), 1 else.
extern "C" __global__ void pgser_lambdas(int agents, int p, int n, float alpha, int td3bc,
                                         const double* __restrict__ sums, float* __restrict__ lambda) {
    PGSER_FOR(a, agents) {
        float abs_sum = 0.0f;
        for (int q = 0; q < p; ++q) abs_sum += (float)sums[(a * p + q) * PGSER_SUMS + PGSER_SUM_PI_ABS];
        lambda[a] = td3bc ? alpha * (1.0f / (abs_sum / (float)n)) : 1.0f;
    }
}

// ∂L/∂u for the actor's top layer, [A, n, act]: (λ·∂(−Q₁/n)/∂π + 2(π − a)/(n·d) [TD3+BC]
// + 2·l2·π/(n·d)) · (1 − π²); scale = 2/(n·d). dpi is [A, n, act], spi [A, n, W].
extern "C" __global__ void pgser_actor_grad(int agents, int n, int act, int W, const float* __restrict__ spi,
                                            const float* __restrict__ dpi,
                                            const float* __restrict__ action,
                                            const float* __restrict__ lambda, int bc, float l2,
                                            float scale, float* __restrict__ g) {
    PGSER_FOR(i, (long long)agents * n * act) {
        const long long row = i / act;
        const int j = (int)(i % act);
        const float pi = spi[row * W + (W - act) + j];
        float d = lambda[row / n] * dpi[i];
        if (bc) d += scale * (pi - action[i]);
        if (l2 > 0.0f) d += scale * l2 * pi;
        g[i] = d * (1.0f - pi * pi);
    }
}

// Per (agent, part): Σᵢⱼ (πᵢⱼ − aᵢⱼ)² and Σᵢⱼ πᵢⱼ², rows then action dimensions, in order.
extern "C" __global__ void pgser_actor_sums(int agents, int n, int p, int act, int W,
                                            const float* __restrict__ spi,
                                            const float* __restrict__ action, int bc, float l2,
                                            double* __restrict__ sums) {
    PGSER_FOR(i, (long long)agents * p) {
        const long long a = i / p;
        const int part = (int)(i % p);
        double bc_sum = 0.0, l2_sum = 0.0;
        PGSER_UNROLL
        for (long long r = pgser_part_start(n, p, part); r < pgser_part_start(n, p, part + 1); ++r) {
            for (int j = 0; j < act; ++j) {
                const float pi = spi[(a * n + r) * W + (W - act) + j];
                if (bc) {
                    const float diff = pi - action[(a * n + r) * act + j];
                    bc_sum += (double)(diff * diff);
                }
                if (l2 > 0.0f) l2_sum += (double)(pi * pi);
            }
        }
        sums[i * PGSER_SUMS + PGSER_SUM_BC] = bc_sum;
        sums[i * PGSER_SUMS + PGSER_SUM_L2] = l2_sum;
    }
}

// Adam (PyTorch's formulation) on every member's parameters from the sum of its parts' gradients
// (in part order), and where consts[PGSER_POLYAK] is set, the target's Polyak step from the new
// parameters in the same pass. grad is [members, p, len]; consts holds this update's step size,
// √(1 − β₂ᵗ), 1 − τ and τ, so that a captured graph needs no new arguments per update.
extern "C" __global__ void pgser_adam(long long members, long long len, int p, float* __restrict__ w,
                                      float* __restrict__ m1, float* __restrict__ m2,
                                      float* __restrict__ target, const float* __restrict__ grad,
                                      const float* __restrict__ consts, float b1, float nb1, float b2,
                                      float nb2, float eps) {
    const float step_size = consts[PGSER_STEP_SIZE], bc2_sqrt = consts[PGSER_BC2_SQRT];
    const float keep = consts[PGSER_KEEP], take = consts[PGSER_TAKE];
    const bool polyak = consts[PGSER_POLYAK] != 0.0f;
    PGSER_FOR(i, members * len) {
        const long long m = i / len, e = i % len;
        float g = grad[(m * p) * len + e];
        for (int q = 1; q < p; ++q) g += grad[(m * p + q) * len + e];
        const float mv = m1[i] * b1 + g * nb1;
        const float vv = m2[i] * b2 + g * g * nb2;
        m1[i] = mv;
        m2[i] = vv;
        const float pv = w[i] - mv / (sqrtf(vv) / bc2_sqrt + eps) * step_size;
        w[i] = pv;
        if (polyak) target[i] = target[i] * keep + pv * take;
    }
}

// The smallest of K critics' values per row ([K, n] → [n]): the score Alg. 2 ranks swaps by.
extern "C" __global__ void pgser_min_q(int K, int n, const float* __restrict__ q, float* __restrict__ out) {
    PGSER_FOR(r, n) {
        float v = PGSER_INF;
        for (int k = 0; k < K; ++k) v = fminf(v, q[(long long)k * n + r]);
        out[r] = v;
    }
}

// π = tanh(u), in place.
extern "C" __global__ void pgser_tanh(long long count, float* __restrict__ x) {
    PGSER_FOR(i, count) x[i] = tanhf(x[i]);
}

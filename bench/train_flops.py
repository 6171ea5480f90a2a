"""Matmul FLOPs of one goal-conditioned TD3+BC / TD3 update, shared by the training peers and bench_grid.py.

Counted per agent and per *critic* update, with the actor and the targets moving on every
`policy_freq`-th one (so an actor update counts 1/policy_freq). Only the matrix products of the
linear layers count (bias adds, ReLU, tanh, the normaliser, losses, Adam and Polyak are
O(B·width) or O(params) and left out). A layer in -> out on a batch of B rows costs:

    forward                     2·B·in·out
    backward of a trained layer 4·B·in·out   (input gradient + weight gradient: "x2 more")
    backward through a net that is only differentiated for its input (Q1 in the actor step):
                                2·B·in·out   (input gradient only)

With F_a = 2·B·((obs+goal)·H + (L-1)·H² + H·act)       (actor forward, L = 4 layers, H = hidden)
     F_c = 2·B·((obs+goal+act)·H + (L-1)·H² + H)        (one critic forward)

    critic update = F_a                 target actor on s'
                  + 2·F_c               both target critics
                  + 2·3·F_c             both critics, forward + backward
    actor update  = 3·F_a               actor forward + backward
                  + 2·F_c               Q1 forward + its input gradient (no weight gradient)
    per update    = critic update + actor update / policy_freq

FetchPush dims (obs 25, goal 3, act 4), H = 256, B = 512, policy delay 2:
    F_a = 142,606,336   F_c = 142,868,480
    critic update 1,285,554,176 + actor update 713,555,968 / 2 = 1,642,332,160 FLOP ≈ 1.64 GFLOP,
the figure the "many agents per process" issue states.

Two deliberate simplifications, the same for every peer so GFLOP/s stay comparable:
* The first layer of a net whose input needs no gradient (every net except Q1 in the actor step)
  needs no input gradient; autograd and XLA skip it, the count above does not (~1.2 % over).
* train_peer.py (as sfujim/TD3_BC) does not freeze the critics in the actor step, so its
  backward also computes Q1's weight gradients, which are then thrown away (critic_opt.zero_grad()
  before the next critic step): it executes F_c/2 more per update (≈ 1.71 GFLOP in all) for the
  same result. The stacked and JAX peers differentiate the actor loss for the actor's parameters
  only. The useful-work count above is the one reported for all of them.
"""
from __future__ import annotations

N_LAYERS = 4  # in -> H -> H -> H -> out


def net_forward_flops(batch: int, inp: int, hidden: int, out: int, layers: int = N_LAYERS) -> int:
    return 2 * batch * (inp * hidden + (layers - 2) * hidden * hidden + hidden * out)


def update_flops(obs: int, goal: int, act: int, hidden: int, batch: int, policy_freq: int = 2) -> dict:
    """FLOPs per agent: {'critic_update', 'actor_update', 'per_update'} (per_update as defined above)."""
    fa = net_forward_flops(batch, obs + goal, hidden, act)
    fc = net_forward_flops(batch, obs + goal + act, hidden, 1)
    critic = fa + 2 * fc + 2 * 3 * fc
    actor = 3 * fa + 2 * fc
    return {"actor_forward": fa, "critic_forward": fc, "critic_update": critic, "actor_update": actor,
            "per_update": critic + actor / policy_freq}


def flops_per_update(obs: int, goal: int, act: int, hidden: int, batch: int, policy_freq: int = 2) -> float:
    return update_flops(obs, goal, act, hidden, batch, policy_freq)["per_update"]


if __name__ == "__main__":
    f = update_flops(25, 3, 4, 256, 512)
    print({k: f"{v:,.0f}" for k, v in f.items()})

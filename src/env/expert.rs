//! Scripted experts for the four Fetch tasks: the "expert" data of WGCSL/GoFAR-style datasets,
//! made without a trained agent.
//!
//! Each controller is a pure function of one observation and its desired goal, as a trained
//! policy would be: no memory of earlier steps, no simulator state. Phases ("go above the
//! object", "descend", "grasp", "carry") are read off the observation itself, so a controller
//! recovers by itself when an object slips or is knocked away, and a noisy action never leaves
//! it in a phase it cannot leave.
//!
//! Final-step success over 100 episodes (seeds 0–99, `tests/collect.rs`): Reach 1.00, Push
//! 0.99, PickAndPlace 1.00, Slide 0.80 (0.785 over seeds 1000–1999). With action noise
//! σ = 0.1: 1.00, 0.97, 1.00, 0.23; σ = 0.2: 1.00, 0.89, 0.97, 0.03. Slide is the fragile one:
//! its strikes need millimetre alignment and a speed right to a few percent (`expert_slide.rs`).
//!
//! Observation layout (docs/domain.md; `fetch_obs.rs`): grip_pos 0..3, object_pos 3..6, object −
//! grip 6..9, finger qpos 9..11, object euler 11..14, object velocity relative to the gripper
//! · dt 14..17, object angular velocity · dt 17..20, gripper velocity · dt 20..23, finger
//! velocity · dt 23..25. Actions move the gripper's mocap target by `action[..3] · 5 cm` per step;
//! `action[3]` opens (+1) or closes (−1) the fingers (PickAndPlace only).

use super::Obs;

/// Largest position change one action asks for (`_set_action` scales by 0.05).
const MAX_STEP: f64 = 0.05;

/// A scripted controller for one Fetch task.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Expert {
    Reach,
    Push,
    PickAndPlace,
    Slide,
}

type V3 = [f64; 3];

fn v3(s: &[f64]) -> V3 {
    [s[0], s[1], s[2]]
}

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm_xy(a: V3) -> f64 {
    a[0].hypot(a[1])
}

/// The action that moves the gripper from `grip` towards `target` at `gain` × the distance
/// per step (1 = all the way in one step), clipped to the action box.
fn toward(grip: V3, target: V3, gain: f64, fingers: f64) -> [f64; 4] {
    let d = sub(target, grip);
    let c = |x: f64| (gain * x / MAX_STEP).clamp(-1.0, 1.0);
    [c(d[0]), c(d[1]), c(d[2]), fingers]
}

/// The push line: unit xy direction from the object to the goal, and the distance left.
fn line(obj: V3, goal: V3) -> ([f64; 2], f64) {
    let (dx, dy) = (goal[0] - obj[0], goal[1] - obj[1]);
    let dist = dx.hypot(dy);
    if dist < 1e-9 { ([1.0, 0.0], 0.0) } else { ([dx / dist, dy / dist], dist) }
}

/// The gripper's position relative to the object in the frame of a push direction: (distance
/// along `dir`, negative when behind the object; lateral offset).
fn along_across(grip: V3, obj: V3, dir: [f64; 2]) -> (f64, f64) {
    let (rx, ry) = (grip[0] - obj[0], grip[1] - obj[1]);
    (rx * dir[0] + ry * dir[1], rx * dir[1] - ry * dir[0])
}

impl Expert {
    /// The controller for a task name, if pgser has one.
    pub fn for_task(name: &str) -> Option<Expert> {
        Some(match name {
            "FetchReach" => Expert::Reach,
            "FetchPush" => Expert::Push,
            "FetchPickAndPlace" => Expert::PickAndPlace,
            "FetchSlide" => Expert::Slide,
            _ => return None,
        })
    }

    /// The action for one observation.
    pub fn act(self, obs: &Obs) -> [f64; 4] {
        let o = &obs.observation;
        let goal = v3(&obs.desired_goal);
        let grip = v3(&o[..3]);
        match self {
            Expert::Reach => toward(grip, goal, 1.0, 0.0),
            Expert::Push => push(grip, v3(&o[3..6]), goal),
            Expert::PickAndPlace => pick_and_place(o, grip, goal),
            Expert::Slide => slide::act(o, grip, goal),
        }
    }
}

/// Push: get behind the block on the goal→block line (from above, so the approach cannot knock
/// the block), descend to its height, then push along the line. The line is recomputed from the
/// block's position every step, so a block that turns or drifts is steered back.
fn push(grip: V3, obj: V3, goal: V3) -> [f64; 4] {
    /// Gripper centre to block centre when pushing (block half-width 2.5 cm + finger).
    const BACK: f64 = 0.05;
    /// Height above the block at which the gripper travels.
    const CLEAR: f64 = 0.06;
    let (dir, dist) = line(obj, goal);
    if dist < 0.01 {
        return [0.0; 4];
    }
    let behind = [obj[0] - dir[0] * BACK, obj[1] - dir[1] * BACK, obj[2]];
    let (along, across) = along_across(grip, obj, dir);
    let low = grip[2] < obj[2] + 0.02;
    if low && along < -0.02 && across.abs() < 0.02 {
        // Push: aim at where the gripper is when the block sits on the goal, a few cm ahead
        // of the contact point, and pull back onto the line.
        let adv = dist.min(0.03);
        let target = [behind[0] + dir[0] * adv, behind[1] + dir[1] * adv, obj[2]];
        return toward(grip, target, 1.0, 0.0);
    }
    let off = norm_xy(sub(behind, grip));
    if off < 0.015 {
        return toward(grip, behind, 1.0, 0.0);
    }
    if grip[2] < obj[2] + CLEAR - 0.02 {
        // Too low to travel: straight up first.
        return toward(grip, [grip[0], grip[1], obj[2] + CLEAR], 1.0, 0.0);
    }
    toward(grip, [behind[0], behind[1], obj[2] + CLEAR], 1.0, 0.0)
}

/// Pick and place: above the block with open fingers, down, close, and once the fingers hold
/// it, carry it to the goal. "Holding" is read off the observation (block between the fingers,
/// fingers closed to about the block's 5 cm and no longer moving), so a dropped block is simply
/// picked up again.
fn pick_and_place(o: &[f64], grip: V3, goal: V3) -> [f64; 4] {
    const OPEN: f64 = 1.0;
    const CLOSE: f64 = -1.0;
    let obj = v3(&o[3..6]);
    let rel = sub(obj, grip);
    let fingers = o[9] + o[10];
    // Finger velocity · dt back to metres per second (dt = 0.04 s).
    let finger_speed = (o[23].abs() + o[24].abs()) / 0.04;
    let between_fingers = norm_xy(rel) < 0.015 && rel[2].abs() < 0.015;
    if between_fingers && fingers < 0.06 && finger_speed < 0.05 {
        return toward(grip, goal, 1.0, CLOSE);
    }
    if between_fingers {
        // Close in place and wait for the grip to settle before lifting.
        return toward(grip, obj, 1.0, CLOSE);
    }
    if norm_xy(rel) < 0.01 {
        // Right above it: straight down, fingers open.
        return toward(grip, obj, 1.0, OPEN);
    }
    let above = [obj[0], obj[1], obj[2] + 0.05];
    if grip[2] < obj[2] + 0.03 && norm_xy(rel) < 0.06 {
        // Low and beside it: up first, so the fingers do not knock it away.
        return toward(grip, [grip[0], grip[1], above[2]], 1.0, OPEN);
    }
    toward(grip, above, 1.0, OPEN)
}

#[path = "expert_slide.rs"]
mod slide;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::make;

    /// Final-step success over `n` seeded episodes (no noise).
    fn success(task: &str, n: u64) -> usize {
        let expert = Expert::for_task(task).unwrap();
        let mut env = make(task).unwrap();
        (0..n)
            .filter(|&seed| {
                let mut obs = env.reset(Some(seed));
                let mut ok = false;
                for _ in 1..env.task().t {
                    let step = env.step(&expert.act(&obs));
                    ok = step.success;
                    obs = step.obs;
                }
                ok
            })
            .count()
    }

    // Quick smoke checks; tests/collect.rs measures 100 episodes per task through `collect`.
    #[test]
    fn experts_solve_easy_seeds() {
        assert_eq!(success("FetchReach", 5), 5);
        assert!(success("FetchPush", 5) >= 4);
        assert!(success("FetchPickAndPlace", 5) >= 4);
    }

    #[test]
    fn clean_shots_are_decomposed_along_two_directions() {
        // 30° lies between the 0° and 45° shots: first the 45° leg (more sideways).
        let d = [0.4, 0.4 * 30f64.to_radians().tan()];
        let shot = slide::plan(d, |_| 0.0);
        assert!((shot.dir[0] - shot.dir[1]).abs() < 1e-12, "{:?}", shot.dir);
        // What is left after it lies on the 0° line.
        let left = [d[0] - shot.dir[0] * shot.length, d[1] - shot.dir[1] * shot.length];
        assert!(left[1].abs() < 1e-12 && left[0] > 0.0, "{left:?}");
        // A goal straight ahead is one shot.
        let shot = slide::plan([0.3, 0.005], |_| 0.0);
        assert_eq!((shot.dir, shot.length), ([1.0, 0.0], 0.3));
    }
}

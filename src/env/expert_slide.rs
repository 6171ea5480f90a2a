//! The FetchSlide expert: strikes along directions the puck keeps, at the speed friction turns
//! into the right distance.
//!
//! Three facts of the simulated table, measured, shape it:
//! * The puck slides with constant (Coulomb) deceleration, μ·g = 0.98 m/s² along an axis, and
//!   √2 less diagonally: MuJoCo's default pyramidal friction cone bounds |fx| + |fy|, not the
//!   force's length. So a puck launched at speed v stops after v²/(2a): a release speed, not a
//!   push distance, sets where it ends.
//! * The puck leaves along the contact normal, and the gripper's footprint is two square finger
//!   blocks side by side: a side face (±90°) pushes straight from anywhere on it, a corner
//!   (±45°) from within a few millimetres of it, a finger's end (0°, 180°) when the puck meets
//!   one finger squarely. Any other direction veers towards one of these. So only these eight
//!   directions are struck, and a goal between two of them takes two strikes.
//! * A strike from rest at action a over two steps launches the puck at ≈ 0.043·a + 0.001 m per
//!   step (0.041·a diagonally), and beyond x ≈ 1.05 m the arm follows x actions more slowly.

use super::{MAX_STEP, V3, norm_xy, sub, toward, v3};

/// Clean strike directions (degrees) with the gripper's lateral offset from the line through
/// the puck's centre that makes them clean (the 0°/180° offsets put the puck on one finger).
const SHOTS: [(f64, f64); 10] = [
    (0.0, 0.013),
    (0.0, -0.013),
    (45.0, 0.002),
    (90.0, 0.0),
    (135.0, 0.0),
    (180.0, 0.013),
    (180.0, -0.013),
    (-135.0, 0.0),
    (-90.0, 0.0),
    (-45.0, -0.002),
];
/// Table deceleration along an axis, metres per step² (μ·g·dt² = 0.1 · 9.81 · 0.04²).
const DECEL: f64 = 0.00157;
/// Launch speed per unit of action, metres per step, along an axis and diagonally (measured).
const LAUNCH_AXIS: f64 = 0.0433;
const LAUNCH_DIAGONAL: f64 = 0.041;
/// Launch speed at action 0 of the linear fit above.
const LAUNCH_OFFSET: f64 = 0.001;
/// Close enough: within this of the goal the puck is left alone (success is < 5 cm, and a
/// strike this short is shorter than the smallest reliable one).
const DONE: f64 = 0.03;
/// Puck speed (metres per step) below which it counts as at rest.
const REST: f64 = 0.002;
/// Height above the puck at which the gripper travels.
const CLEAR: f64 = 0.05;
/// A single strike is taken when the goal is within this of its line.
const MISS: f64 = 0.012;
/// Lateral alignment needed before striking.
const ALIGN: f64 = 0.004;
/// Gap between gripper and puck when lined up.
const GAP: f64 = 0.005;

/// One strike: unit direction, the gripper's lateral offset, and the distance to cover.
pub(super) struct Shot {
    pub dir: [f64; 2],
    pub offset: f64,
    pub length: f64,
}

fn unit(deg: f64) -> [f64; 2] {
    let r = deg.to_radians();
    [r.cos(), r.sin()]
}

fn cross(a: [f64; 2], b: [f64; 2]) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

/// The next strike towards a goal `d` away: along one clean direction if the goal lies on it,
/// else along the more sideways of the two clean directions around the goal's bearing, for as
/// long as it takes to put the goal on the other one (which is the final strike). The 0° and
/// 180° strikes have two offsets; `across(u)` (the gripper's lateral offset for a direction)
/// picks the nearer.
pub(super) fn plan(d: [f64; 2], across: impl Fn([f64; 2]) -> f64) -> Shot {
    let mut best: Option<Shot> = None;
    for &(deg, offset) in &SHOTS {
        let u = unit(deg);
        let along = d[0] * u[0] + d[1] * u[1];
        if along <= 0.0 || cross(d, u).abs() >= MISS {
            continue;
        }
        if best.as_ref().is_none_or(|b| (across(u) - offset).abs() < (across(b.dir) - b.offset).abs()) {
            best = Some(Shot { dir: u, offset, length: along });
        }
    }
    if let Some(b) = best {
        return b;
    }
    let bearing = d[1].atan2(d[0]).to_degrees();
    let lo = (bearing / 45.0).floor() * 45.0;
    let sideways = |deg: f64| (90.0 - deg.abs()).abs();
    let (first, last) = if sideways(lo + 45.0) < sideways(lo) { (lo + 45.0, lo) } else { (lo, lo + 45.0) };
    let (ua, ub) = (unit(first), unit(last));
    // d = la·ua + lb·ub  ⇒  la = (d × ub) / (ua × ub)
    let length = (cross(d, ub) / cross(ua, ub)).max(0.0);
    let first = if first <= -180.0 { first + 360.0 } else { first };
    let offset = SHOTS.iter().find(|s| s.0 == first).map_or(0.0, |s| s.1);
    Shot { dir: ua, offset, length }
}

/// Deceleration of a puck sliding along unit direction `u` (pyramidal friction cone).
fn decel(u: [f64; 2]) -> f64 {
    DECEL / (u[0].abs() + u[1].abs())
}

/// How fast the gripper follows an x action at puck height relative to near the robot
/// (measured: 1 up to x = 1.05 m, 0.87 at 1.15, 0.55 at 1.25 on the centre line y = 0.75,
/// slower off it).
fn x_speed(grip: V3) -> f64 {
    let x = grip[0] + 0.7 * (grip[1] - 0.75).powi(2);
    if x <= 1.05 {
        1.0
    } else if x <= 1.15 {
        1.0 - 1.3 * (x - 1.05)
    } else {
        (0.87 - 3.2 * (x - 1.15)).max(0.2)
    }
}

/// The Slide action: strike when lined up behind the puck at rest, wait (travelling to the
/// next strike's start, above the table) while it slides, otherwise line up.
pub(super) fn act(o: &[f64], grip: V3, goal: V3) -> [f64; 4] {
    let puck = v3(&o[3..6]);
    // The object's velocity relative to the gripper plus the gripper's: the puck's own.
    let vel: V3 = std::array::from_fn(|i| o[14 + i] + o[20 + i]);
    let speed = norm_xy(vel);
    let moving = speed > REST;

    // Strike: planned from where the puck is now.
    let now = [grip[0] - puck[0], grip[1] - puck[1]];
    let strike = plan([goal[0] - puck[0], goal[1] - puck[1]], |u| cross(u, now));
    let u = strike.dir;
    // Contact distance: puck radius plus the footprint's reach along u (face or corner).
    let back = 0.025 + (0.0154 * u[0].abs() + 0.016 * u[1].abs()).max(0.0154) + GAP;
    let along = now[0] * u[0] + now[1] * u[1];
    let across = cross(u, now) - strike.offset;
    let need = (2.0 * decel(u) * strike.length).sqrt();
    let low = grip[2] < puck[2] + 0.015;
    let goal_far = (goal[0] - puck[0]).hypot(goal[1] - puck[1]) >= DONE;
    if goal_far && low && along < -0.03 && along > -back - 0.01 && across.abs() < ALIGN && speed < 0.95 * need {
        // Two steps at this action launch the puck at `need`; keep going while it is slower.
        let per_action = if u[0].abs() > 0.5 && u[1].abs() > 0.5 { LAUNCH_DIAGONAL } else { LAUNCH_AXIS };
        let run = ((need - LAUNCH_OFFSET) / per_action).clamp(0.2, 1.0);
        let pull = (-across / MAX_STEP).clamp(-0.3, 0.3);
        let n = [-u[1], u[0]];
        // Far out the arm follows x actions slowly: ask for more (√ of the measured slowdown,
        // which fits the launch speeds best).
        let a = [(u[0] * run + n[0] * pull) / x_speed(grip).sqrt(), u[1] * run + n[1] * pull];
        let over = a[0].abs().max(a[1].abs()).max(1.0);
        let hold_z = ((puck[2] - grip[2]) / MAX_STEP).clamp(-1.0, 1.0);
        return [a[0] / over, a[1] / over, hold_z, 0.0];
    }

    // Otherwise plan from where the puck will come to rest.
    let rest = if moving {
        let dir = [vel[0] / speed, vel[1] / speed];
        let coast = speed * speed / (2.0 * decel(dir));
        [puck[0] + dir[0] * coast, puck[1] + dir[1] * coast, puck[2]]
    } else {
        puck
    };
    let d = [goal[0] - rest[0], goal[1] - rest[1]];
    if d[0].hypot(d[1]) < DONE {
        return [0.0; 4];
    }
    let rel = [grip[0] - rest[0], grip[1] - rest[1]];
    let shot = plan(d, |u| cross(u, rel));
    let u = shot.dir;
    let n = [-u[1], u[0]];
    let back = 0.025 + (0.0154 * u[0].abs() + 0.016 * u[1].abs()).max(0.0154) + GAP;
    let stage = [rest[0] - u[0] * back + n[0] * shot.offset, rest[1] - u[1] * back + n[1] * shot.offset, puck[2]];
    let travel = puck[2] + CLEAR;
    let near_stage = norm_xy(sub(stage, grip)) < 0.01;
    if moving {
        // Never come down next to a sliding puck: wait above the next start.
        if grip[2] < travel - 0.02 && !near_stage {
            return toward(grip, [grip[0], grip[1], travel], 1.0, 0.0);
        }
        return toward(grip, [stage[0], stage[1], grip[2].max(travel)], 1.0, 0.0);
    }
    let rel_along = rel[0] * u[0] + rel[1] * u[1];
    if (low && rel_along < -back - 0.01) || near_stage {
        // Behind the puck already (nothing in the way), or above the start: go straight there.
        return toward(grip, stage, 1.0, 0.0);
    }
    if grip[2] < travel - 0.02 {
        return toward(grip, [grip[0], grip[1], travel], 1.0, 0.0);
    }
    toward(grip, [stage[0], stage[1], travel], 1.0, 0.0)
}

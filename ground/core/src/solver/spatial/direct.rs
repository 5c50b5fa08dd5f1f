//! The direct transcription in three dimensions: the independent cross-check of the spatial
//! indirect solver, by [`crate::solver::direct`]'s method and SQP.
//!
//! State (x, y, z, vx, vy, vz, m); on each of K equal segments the control (w_r, w_t, w_n, s) is
//! held in the local RTN frame of `onboard::spatial` (radial, transverse, normal along the
//! angular momentum r x v), with |w| <= s <= 1, so that (s, w/|w|) is exactly an onboard
//! [`RtnCommand`]. Cost (T/c) h sum s_k; terminal conditions r(tf), v(tf) on the inclined target
//! orbit at a free anomaly nu_f (transfers) or equal to the body's state at tf (rendezvous).
//! Only the dynamics and the target are three-dimensional here: the segment maps' variational
//! equations, the lifted QP, the trust region and the multipliers are the planar module's,
//! written once for both dimensions.

use num_dual::{Dual2_64, DualNum, DualSVec64};
use onboard::dynamics::PropagationError;
use onboard::integrator::{IntegrationError, Tolerances};
use onboard::spatial::{propagate_rtn, RtnCommand, SpatialCraftState};
use shared::orbit::SpatialState;
use shared::spacecraft::CanonicalSpacecraft;

use super::{SpatialOrbitShape, SpatialRendezvous, SpatialTransfer};
use crate::solver::direct::{
    integrate_segment, integrate_segment_jacobian, nodes, refine_transcription, solve_transcription, thrust_norm,
    DirectError, DirectGuess, DirectOptions, DirectSolution, SegmentJacobians, Transcription,
};

/// State (x, y, z, vx, vy, vz, m).
pub const STATE3: usize = 7;
/// Segment control (w_r, w_t, w_n, s): RTN thrust vector (|w| <= s) and throttle (mass flow).
pub const CONTROL3: usize = 4;
const INPUTS3: usize = STATE3 + CONTROL3;
/// Terminal conditions (r and v).
const TERMINAL3: usize = 6;

/// A node state (x, y, z, vx, vy, vz, m): canonical units, mass a fraction of m0.
pub type State3 = [f64; STATE3];
/// A segment control (w_r, w_t, w_n, s): RTN thrust vector in units of the maximum thrust, and
/// throttle.
pub type Control3 = [f64; CONTROL3];
/// Controls (and nu_f) of the spatial direct problem.
pub type SpatialDirectGuess = DirectGuess<CONTROL3>;
/// A spatial direct solution: the planar one's fields, with 7 states and 4 controls.
pub type SpatialDirectSolution = DirectSolution<STATE3, CONTROL3>;

/// Right-hand side with the control held in the RTN frame: the thrust acceleration is
/// (T/m) (w_r r_hat + w_t t_hat + w_n n_hat), n_hat = r x v / |r x v|, t_hat = n_hat x r_hat;
/// the mass flow -(T/c) s.
fn rhs3<D: DualNum<Primitive = f64> + Copy>(
    y: &[D; STATE3],
    p: &[D; CONTROL3],
    sc: &CanonicalSpacecraft,
) -> [D; STATE3] {
    let r = [y[0], y[1], y[2]];
    let v = [y[3], y[4], y[5]];
    let m = y[6];
    let [wr, wt, wn, s] = *p;
    let cross = |a: &[D; 3], b: &[D; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    let rn = r2.sqrt();
    let inv_r3 = (r2 * rn).recip();
    let h = cross(&r, &v);
    let hn = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
    let r_hat = r.map(|x| x / rn);
    let n_hat = h.map(|x| x / hn);
    let t_hat = cross(&n_hat, &r_hat);
    let k = m.recip() * sc.thrust;
    let acc = |i: usize| -r[i] * inv_r3 + k * (wr * r_hat[i] + wt * t_hat[i] + wn * n_hat[i]);
    [
        v[0],
        v[1],
        v[2],
        acc(0),
        acc(1),
        acc(2),
        -s * (sc.thrust / sc.exhaust_speed),
    ]
}

/// The state at the end of a segment of duration `h` with the control held in the RTN frame.
pub fn spatial_segment_map(
    sc: &CanonicalSpacecraft,
    x: &State3,
    p: &Control3,
    h: f64,
    tol: &Tolerances,
) -> Result<State3, IntegrationError> {
    integrate_segment(|y: &State3, p: &Control3| rhs3(y, p, sc), x, p, h, tol)
}

fn spatial_jacobians(
    sc: &CanonicalSpacecraft,
    x: &State3,
    p: &Control3,
    h: f64,
    tol: &Tolerances,
) -> Result<SegmentJacobians<STATE3, CONTROL3>, IntegrationError> {
    integrate_segment_jacobian::<_, STATE3, CONTROL3, INPUTS3, { STATE3 + STATE3 * INPUTS3 }>(
        |y: &[DualSVec64<INPUTS3>; STATE3], p: &[DualSVec64<INPUTS3>; CONTROL3]| rhs3(y, p, sc),
        x,
        p,
        h,
        tol,
    )
}

/// Where the spacecraft must be at tf.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SpatialDirectTarget {
    /// Transfer: a point of the (inclined) target orbit at a free true anomaly nu_f.
    Orbit(SpatialOrbitShape),
    /// Rendezvous: the body's state at tf.
    Body(SpatialState),
}

/// A spatial direct problem: from `departure` with `initial_mass` to `target` in
/// `time_of_flight`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpatialDirectProblem {
    /// State at t = 0.
    pub departure: SpatialState,
    /// Mass at t = 0 (fraction of the mass the thrust is scaled by).
    pub initial_mass: f64,
    /// Time of flight (t*).
    pub time_of_flight: f64,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
    /// The orbit or the body's arrival state.
    pub target: SpatialDirectTarget,
}

impl SpatialDirectProblem {
    /// The direct problem of an indirect spatial rendezvous: meet its arrival state.
    pub fn rendezvous(problem: &SpatialRendezvous) -> Self {
        Self {
            departure: problem.departure,
            initial_mass: problem.initial_mass,
            time_of_flight: problem.time_of_flight,
            spacecraft: problem.spacecraft,
            target: SpatialDirectTarget::Body(problem.arrival),
        }
    }

    /// The direct problem of an indirect spatial transfer: reach its target orbit anywhere.
    pub fn transfer(problem: &SpatialTransfer) -> Self {
        Self {
            departure: problem.departure,
            initial_mass: problem.initial_mass,
            time_of_flight: problem.time_of_flight,
            spacecraft: problem.spacecraft,
            target: SpatialDirectTarget::Orbit(problem.target),
        }
    }

    /// The direct problem of a goal (a problem file's or a family draw's).
    pub fn of_goal(goal: &crate::spatial::SpatialGoal) -> Self {
        match goal {
            crate::spatial::SpatialGoal::Rendezvous(p) => Self::rendezvous(p),
            crate::spatial::SpatialGoal::Transfer(p) => Self::transfer(p),
        }
    }

    /// The states at every node x_0..x_K for the given controls on equal segments.
    pub fn nodes(&self, controls: &[Control3], tol: &Tolerances) -> Result<Vec<State3>, IntegrationError> {
        let h = self.time_of_flight / controls.len() as f64;
        nodes(self.initial_state(), controls, |x, p| {
            spatial_segment_map(&self.spacecraft, x, p, h, tol)
        })
    }

    /// Flies the controls on equal segments through `onboard::spatial::propagate_rtn` (throttle
    /// s, direction w/|w|; coasting where s < 1e-12) and returns the final state.
    pub fn fly_rtn(&self, controls: &[Control3], tol: &Tolerances) -> Result<State3, PropagationError> {
        self.fly_onboard(controls, self.time_of_flight / controls.len() as f64, tol)
    }

    /// The largest violation of the terminal conditions at final state `x` (and nu_f for a
    /// transfer).
    pub fn terminal_violation(&self, x: &State3, nu_f: f64) -> f64 {
        let t = self.target_point(nu_f);
        (0..TERMINAL3).map(|i| (x[i] - t[i].0).abs()).fold(0.0, f64::max)
    }
}

impl Transcription<STATE3, CONTROL3, TERMINAL3> for SpatialDirectProblem {
    fn spacecraft(&self) -> &CanonicalSpacecraft {
        &self.spacecraft
    }

    fn initial_state(&self) -> State3 {
        let (r, v) = (self.departure.r, self.departure.v);
        [r[0], r[1], r[2], v[0], v[1], v[2], self.initial_mass]
    }

    fn time_of_flight(&self) -> f64 {
        self.time_of_flight
    }

    fn free_anomaly(&self) -> bool {
        matches!(self.target, SpatialDirectTarget::Orbit(_))
    }

    fn segment_map(&self, x: &State3, p: &Control3, h: f64, tol: &Tolerances) -> Result<State3, IntegrationError> {
        spatial_segment_map(&self.spacecraft, x, p, h, tol)
    }

    fn segment_jacobians(
        &self,
        x: &State3,
        p: &Control3,
        h: f64,
        tol: &Tolerances,
    ) -> Result<SegmentJacobians<STATE3, CONTROL3>, IntegrationError> {
        spatial_jacobians(&self.spacecraft, x, p, h, tol)
    }

    fn target_point(&self, nu: f64) -> [(f64, f64, f64); TERMINAL3] {
        match &self.target {
            SpatialDirectTarget::Orbit(shape) => {
                let o = shape.state_at(Dual2_64::from_re(nu).derivative());
                core::array::from_fn(|i| (o[i].re, o[i].v1, o[i].v2))
            }
            SpatialDirectTarget::Body(s) => {
                let b = [s.r[0], s.r[1], s.r[2], s.v[0], s.v[1], s.v[2]];
                core::array::from_fn(|i| (b[i], 0.0, 0.0))
            }
        }
    }

    fn fly_onboard(&self, controls: &[Control3], h: f64, tol: &Tolerances) -> Result<State3, PropagationError> {
        let mut state = SpatialCraftState {
            orbit: self.departure,
            m: self.initial_mass,
        };
        for c in controls {
            let norm = thrust_norm(c);
            let command = if c[3] < 1e-12 || norm == 0.0 {
                RtnCommand::OFF
            } else {
                RtnCommand {
                    throttle: c[3].min(1.0),
                    radial: c[0] / norm,
                    transverse: c[1] / norm,
                    normal: c[2] / norm,
                }
            };
            state = propagate_rtn(&state, &command, &self.spacecraft, h, tol)?;
        }
        Ok(state.to_array())
    }
}

/// Tangential thrust at a constant throttle on `segments` segments (prograde for a raise of
/// the semi-major axis, retrograde for a lowering), in the departure's plane (no normal
/// component); nu_f the anomaly on the target orbit of the point where that trajectory ends,
/// its position projected on the orbit's plane (0 for a rendezvous).
pub fn tangential_guess(
    problem: &SpatialDirectProblem,
    segments: usize,
    throttle: f64,
    tol: &Tolerances,
) -> Result<SpatialDirectGuess, DirectError> {
    let semi_major = |s: &SpatialState| -0.5 / s.energy();
    let target_a = match &problem.target {
        SpatialDirectTarget::Orbit(shape) => shape.a,
        SpatialDirectTarget::Body(s) => semi_major(s),
    };
    let sign = if target_a >= semi_major(&problem.departure) {
        1.0
    } else {
        -1.0
    };
    let controls = vec![[0.0, sign * throttle, 0.0, throttle]; segments];
    let nu_f = match &problem.target {
        SpatialDirectTarget::Orbit(shape) => {
            let xf = *problem.nodes(&controls, tol)?.last().ok_or(DirectError::Guess)?;
            let (p, q) = shape.perifocal();
            let along = |e: &[f64; 3]| xf[0] * e[0] + xf[1] * e[1] + xf[2] * e[2];
            along(&q).atan2(along(&p))
        }
        SpatialDirectTarget::Body(_) => 0.0,
    };
    Ok(SpatialDirectGuess { controls, nu_f })
}

/// Solves the spatial direct problem on `guess.controls.len()` segments from `guess`, for the
/// running cost of homotopy parameter `eps` (0: fuel-optimal); see
/// [`crate::solver::direct::solve_direct`].
pub fn solve_spatial_direct(
    problem: &SpatialDirectProblem,
    guess: &SpatialDirectGuess,
    eps: f64,
    options: &DirectOptions,
) -> Result<SpatialDirectSolution, DirectError> {
    solve_transcription(problem, guess, eps, options)
}

/// [`solve_spatial_direct`] on `guess`'s mesh and then on `refinements` meshes, each twice as
/// fine and warm-started from the one before: one solution per mesh, coarsest first.
pub fn solve_spatial_direct_refined(
    problem: &SpatialDirectProblem,
    guess: SpatialDirectGuess,
    refinements: usize,
    eps: f64,
    options: &DirectOptions,
) -> Result<Vec<SpatialDirectSolution>, DirectError> {
    refine_transcription(problem, guess, refinements, eps, options)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::direct::{solve_direct, DirectGuess};
    use crate::spatial::SpatialGoal;
    use shared::scenario::{ScenarioKind, SpatialScenario};
    use shared::spacecraft::Spacecraft;

    fn sc() -> CanonicalSpacecraft {
        Spacecraft::MSR_ERO.canonical().unwrap()
    }

    fn tol() -> Tolerances {
        DirectOptions::default().tolerances
    }

    #[test]
    fn segment_jacobian_matches_central_differences() {
        let x = [0.8, 0.55, 0.12, -0.5, 0.75, 0.2, 0.93];
        let p = [0.3, -0.5, 0.4, 0.8];
        let h = 0.12;
        let j = spatial_jacobians(&sc(), &x, &p, h, &tol()).unwrap();
        let plain = spatial_segment_map(&sc(), &x, &p, h, &tol()).unwrap();
        assert!(
            (0..STATE3).all(|i| (j.end[i] - plain[i]).abs() < 1e-12),
            "{:?} vs {plain:?}",
            j.end
        );
        for input in 0..INPUTS3 {
            let delta = 1e-6;
            let shifted = |sign: f64| {
                let (mut xs, mut ps) = (x, p);
                if input < STATE3 {
                    xs[input] += sign * delta;
                } else {
                    ps[input - STATE3] += sign * delta;
                }
                spatial_segment_map(&sc(), &xs, &ps, h, &tol()).unwrap()
            };
            let (plus, minus) = (shifted(1.0), shifted(-1.0));
            for i in 0..STATE3 {
                let fd = (plus[i] - minus[i]) / (2.0 * delta);
                let exact = if input < STATE3 {
                    j.state[(i, input)]
                } else {
                    j.control[(i, input - STATE3)]
                };
                assert!((fd - exact).abs() < 1e-8, "d y{i} / d input{input}: {fd} vs {exact}");
            }
        }
    }

    /// The RTN convention is the onboard one: a segment map equals `propagate_rtn` under the
    /// command (s, w/|w|), out-of-plane thrust and coasting included.
    #[test]
    fn segment_map_agrees_with_the_onboard_rtn_hold() {
        let x = [0.2, -1.1, 0.05, 0.95, 0.1, -0.04, 0.9];
        let commands = [
            (1.0, [0.6, 0.0, 0.8]),
            (0.35, [-0.48, 0.6, -0.64]),
            (0.7, [0.0, 0.0, 1.0]),
            (0.0, [0.0, 1.0, 0.0]),
        ];
        for (throttle, [radial, transverse, normal]) in commands {
            let p = [throttle * radial, throttle * transverse, throttle * normal, throttle];
            let ours = spatial_segment_map(&sc(), &x, &p, 0.24, &tol()).unwrap();
            let command = RtnCommand {
                throttle,
                radial,
                transverse,
                normal,
            };
            let onboard = propagate_rtn(&SpatialCraftState::from_array(&x), &command, &sc(), 0.24, &tol())
                .unwrap()
                .to_array();
            for i in 0..STATE3 {
                assert!(
                    (ours[i] - onboard[i]).abs() < 1e-11,
                    "{throttle}: {ours:?} vs {onboard:?}"
                );
            }
        }
    }

    /// A coplanar draw embedded in three dimensions has the planar direct solution: the same
    /// final mass (both from tangential thrust on the same mesh), no thrust out of the plane,
    /// and the controls flown by `propagate_rtn` reach the target.
    #[test]
    fn a_coplanar_draw_in_three_dimensions_has_the_planar_direct_solution() {
        for (kind, seed, index) in [
            (ScenarioKind::TransferCircular, 7, 3),
            (ScenarioKind::RendezvousCircular, 7, 3),
        ] {
            let scenario = kind.draw(seed, index);
            let segments = scenario.steps as usize;
            let options = DirectOptions::default();
            let planar_guess = DirectGuess::tangential(&scenario, &sc(), segments, 0.5, &tol()).unwrap();
            let planar = solve_direct(&scenario, &sc(), &planar_guess, 0.0, &options).unwrap();
            let goal = SpatialGoal::of_scenario(&SpatialScenario::planar(scenario), sc()).unwrap();
            let problem = SpatialDirectProblem::of_goal(&goal);
            let guess = tangential_guess(&problem, segments, 0.5, &tol()).unwrap();
            let spatial = solve_spatial_direct(&problem, &guess, 0.0, &options).unwrap();
            assert!(
                planar.converged && spatial.converged,
                "{kind:?}: {planar:?}\n{spatial:?}"
            );
            let relative = (spatial.final_mass - planar.final_mass).abs() / planar.final_mass;
            assert!(
                relative < 1e-8,
                "{kind:?}: {} vs {}",
                spatial.final_mass,
                planar.final_mass
            );
            let out_of_plane = spatial.controls.iter().map(|c| c[2].abs()).fold(0.0, f64::max);
            assert!(out_of_plane < 1e-6, "{kind:?}: w_n up to {out_of_plane:e}");
            assert!(spatial.onboard_infeasibility < 1e-8, "{kind:?}: {spatial:?}");
            eprintln!(
                "{kind:?} {seed} #{index}: planar {} spatial {} ({:.2} s, {:.2} s)",
                planar.final_mass, spatial.final_mass, planar.seconds, spatial.seconds
            );
        }
    }
}

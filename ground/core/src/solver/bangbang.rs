//! Structure-fixed shooting of the fuel-optimal (eps = 0) transfer: the throttle is prescribed
//! as alternating coast and full-thrust arcs, the switching times are unknowns, and the switching
//! function must vanish at each of them (rho(t_i) = 0). This is the well-posed way to reach the
//! bang-bang extremal of a transfer between nearly circular orbits, whose single-shooting
//! homotopy path heads for a spread, singular-looking throttle instead (see
//! docs/design/solver.md).
//!
//! Unknowns z = (lambda_0 (5), nu_f, t_1 .. t_S), equations F = (r, v - orbit(nu_f) (4),
//! transversality (1), lambda_m(tf) (1), rho(t_1) .. rho(t_S)). Every arc is propagated with its
//! 10 x 10 state transition matrix (forward-mode duals of the same right-hand side the indirect
//! solver uses), and the Jacobian is assembled exactly, switching times included.

use nalgebra::{Const, SMatrix, SVector};
use num_dual::{Derivative, Dual2_64, DualVec64};
use onboard::integrator::{integrate, IntegrationError, OdeSystem, Tolerances};
use shared::scenario::Scenario;
use shared::spacecraft::CanonicalSpacecraft;

use super::pontryagin::{self, idx, state_costate_rhs_in, switching_function, OptimalControlParams, Regime, Y_LEN};
use super::shooting::{initial_state_costate, orbit_state, ShootingProblem};

/// State-costate + its 10 x 10 transition matrix (column-major after the first 10).
const STM_LEN: usize = Y_LEN + Y_LEN * Y_LEN;

/// Work of one transition-matrix step relative to a plain step (see [`pontryagin::work_done`]).
pub const STM_STEP_WORK: u64 = 10;

type Dual10 = DualVec64<Const<Y_LEN>>;

/// One arc with its throttle branch held fixed (coast or full thrust), with its transition matrix.
struct ArcStm {
    params: OptimalControlParams,
    regime: Regime,
}

impl OdeSystem<STM_LEN> for ArcStm {
    fn derivatives(&self, _t: f64, ys: &[f64; STM_LEN], dydt: &mut [f64; STM_LEN]) {
        let y: [Dual10; Y_LEN] = core::array::from_fn(|i| {
            let row = SVector::<f64, Y_LEN>::from_fn(|k, _| ys[Y_LEN + k * Y_LEN + i]);
            Dual10::new(ys[i], Derivative::some(row))
        });
        let f = state_costate_rhs_in(&y, &self.params, self.regime);
        for (i, fi) in f.iter().enumerate() {
            dydt[i] = fi.re;
            let d = fi.eps.unwrap_generic(Const::<Y_LEN>, Const::<1>);
            for k in 0..Y_LEN {
                dydt[Y_LEN + k * Y_LEN + i] = d[k];
            }
        }
    }
}

/// One arc with its branch held fixed, without the transition matrix.
struct Arc {
    params: OptimalControlParams,
    regime: Regime,
}

impl OdeSystem<Y_LEN> for Arc {
    fn derivatives(&self, _t: f64, y: &[f64; Y_LEN], dydt: &mut [f64; Y_LEN]) {
        *dydt = state_costate_rhs_in(y, &self.params, self.regime);
    }
}

/// The arc regimes of a bang-bang structure: `switches + 1` arcs alternating between coast and
/// full thrust, starting with `first`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Structure {
    /// Regime of the first arc ([`Regime::Coast`] or [`Regime::Full`]).
    pub first: Regime,
    /// Number of switching times (arcs minus one).
    pub switches: usize,
}

impl Structure {
    /// The regime of arc `j` (0-based).
    pub fn regime(&self, j: usize) -> Regime {
        let other = if self.first == Regime::Full {
            Regime::Coast
        } else {
            Regime::Full
        };
        if j.is_multiple_of(2) {
            self.first
        } else {
            other
        }
    }

    /// Number of unknowns (and equations): 5 costates, nu_f, the switching times.
    pub fn unknowns(&self) -> usize {
        6 + self.switches
    }
}

/// The structure-fixed transfer problem, optionally with the first switching time pinned to a
/// value (the transversality condition is then replaced by t_1 - pin = 0: the shift of the burn
/// pattern along nearly circular orbits is then fixed, which leaves a well-conditioned system).
#[derive(Debug, Clone, Copy)]
pub struct BangBangTransfer<'a> {
    /// The transfer to solve.
    pub scenario: &'a Scenario,
    /// Thrust and exhaust speed, canonical.
    pub spacecraft: CanonicalSpacecraft,
    /// The fixed coast / full-thrust arc sequence.
    pub structure: Structure,
    /// First switching time t_1 (t*) to pin, replacing the transversality condition; `None`: free.
    pub pin: Option<f64>,
}

/// Minimum length of an arc: switching times closer than this (or outside [0, tf]) are
/// rejected as an invalid trial point.
const MIN_ARC: f64 = 1e-9;

fn params(spacecraft: CanonicalSpacecraft) -> OptimalControlParams {
    OptimalControlParams { spacecraft, eps: 0.0 }
}

/// Gradient of rho = lambda_m + c |lambda_v| / m - 1 with respect to y.
fn rho_gradient(y: &[f64; Y_LEN], c: f64) -> [f64; Y_LEN] {
    let lv = y[idx::LV].hypot(y[idx::LV + 1]);
    let m = y[idx::M];
    let mut g = [0.0; Y_LEN];
    g[idx::LM] = 1.0;
    g[idx::LV] = c * y[idx::LV] / (lv * m);
    g[idx::LV + 1] = c * y[idx::LV + 1] / (lv * m);
    g[idx::M] = -c * lv / (m * m);
    g
}

/// What a propagation of the structured problem returns: the final state-costate, the states at
/// the switches, and (with sensitivities) dy/dz at the switches and at tf.
pub struct Flight {
    /// State-costate at tf.
    pub y_final: [f64; Y_LEN],
    /// State-costate at each switching time, in order.
    pub y_switch: Vec<[f64; Y_LEN]>,
    /// 10 x n row-major blocks: d y / d z at each switch, then at tf (only with sensitivities).
    pub dy_switch: Vec<Vec<[f64; Y_LEN]>>,
    /// d y(tf) / d z, one column of 10 per unknown (only with sensitivities).
    pub dy_final: Vec<[f64; Y_LEN]>,
}

impl BangBangTransfer<'_> {
    /// The arc boundaries 0, t_1, .., t_S, tf, or an error if they are not increasing.
    fn boundaries(&self, z: &[f64]) -> Result<Vec<f64>, IntegrationError> {
        let tf = self.scenario.time_of_flight();
        let mut b = Vec::with_capacity(self.structure.switches + 2);
        b.push(0.0);
        b.extend_from_slice(&z[6..6 + self.structure.switches]);
        b.push(tf);
        if b.windows(2).any(|w| w[1] - w[0] < MIN_ARC || (w[1] - w[0]).is_nan()) {
            return Err(IntegrationError::InvalidInput);
        }
        Ok(b)
    }

    /// Propagates the arcs; with `sensitivities`, also d y / d z at every switch and at tf.
    pub fn fly(&self, z: &[f64], tolerances: &Tolerances, sensitivities: bool) -> Result<Flight, IntegrationError> {
        let n = self.structure.unknowns();
        assert_eq!(z.len(), n);
        let b = self.boundaries(z)?;
        let p = params(self.spacecraft);
        let mut y = initial_state_costate(self.scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        // G = d y / d z, stored as n columns of length 10.
        let mut g: Vec<[f64; Y_LEN]> = vec![[0.0; Y_LEN]; n];
        for (k, col) in g.iter_mut().enumerate().take(5) {
            col[idx::LR + k] = 1.0;
        }
        let mut flight = Flight {
            y_final: y,
            y_switch: Vec::new(),
            dy_switch: Vec::new(),
            dy_final: Vec::new(),
        };
        for j in 0..=self.structure.switches {
            let regime = self.structure.regime(j);
            let (t0, t1) = (b[j], b[j + 1]);
            if sensitivities {
                let f0 = state_costate_rhs_in(&y, &p, regime);
                let mut ys = [0.0; STM_LEN];
                ys[..Y_LEN].copy_from_slice(&y);
                for k in 0..Y_LEN {
                    ys[Y_LEN + k * Y_LEN + k] = 1.0;
                }
                let (ye, stats) = integrate(&ArcStm { params: p, regime }, t0, &ys, t1, tolerances)
                    .inspect_err(|_| pontryagin::charge_work(u64::from(tolerances.max_steps) * STM_STEP_WORK))?;
                pontryagin::charge_stats(&stats, STM_STEP_WORK);
                let phi = |i: usize, k: usize| ye[Y_LEN + k * Y_LEN + i];
                let y1: [f64; Y_LEN] = core::array::from_fn(|i| ye[i]);
                let f1 = state_costate_rhs_in(&y1, &p, regime);
                // Phi * (G - f0 e_{t0}^T) + f1 e_{t1}^T.
                if j >= 1 {
                    let col = &mut g[6 + j - 1];
                    for i in 0..Y_LEN {
                        col[i] -= f0[i];
                    }
                }
                let mut next: Vec<[f64; Y_LEN]> = vec![[0.0; Y_LEN]; n];
                for (c, out) in g.iter().zip(next.iter_mut()) {
                    for (i, o) in out.iter_mut().enumerate() {
                        *o = (0..Y_LEN).map(|k| phi(i, k) * c[k]).sum();
                    }
                }
                if j < self.structure.switches {
                    let col = &mut next[6 + j];
                    for i in 0..Y_LEN {
                        col[i] += f1[i];
                    }
                }
                g = next;
                y = y1;
            } else {
                let (ye, stats) = integrate(&Arc { params: p, regime }, t0, &y, t1, tolerances)
                    .inspect_err(|_| pontryagin::charge_work(u64::from(tolerances.max_steps)))?;
                pontryagin::charge_stats(&stats, 1);
                y = ye;
            }
            if j < self.structure.switches {
                flight.y_switch.push(y);
                if sensitivities {
                    flight.dy_switch.push(g.clone());
                }
            }
        }
        flight.y_final = y;
        flight.dy_final = g;
        Ok(flight)
    }

    /// The state-costate at time `t` of the structured trajectory of `z`.
    pub fn state_at(&self, z: &[f64], t: f64, tolerances: &Tolerances) -> Result<[f64; Y_LEN], IntegrationError> {
        let b = self.boundaries(z)?;
        let p = params(self.spacecraft);
        let mut y = initial_state_costate(self.scenario, &[z[0], z[1], z[2], z[3], z[4]]);
        for j in 0..=self.structure.switches {
            let end = b[j + 1].min(t);
            if end > b[j] {
                let (ye, stats) = integrate(
                    &Arc {
                        params: p,
                        regime: self.structure.regime(j),
                    },
                    b[j],
                    &y,
                    end,
                    tolerances,
                )?;
                pontryagin::charge_stats(&stats, 1);
                y = ye;
            }
            if end >= t {
                break;
            }
        }
        Ok(y)
    }

    /// Residual (and with `jacobian`, its Jacobian, row-major n x n).
    pub fn evaluate(
        &self,
        z: &[f64],
        tolerances: &Tolerances,
        jacobian: bool,
    ) -> Result<(Vec<f64>, Vec<Vec<f64>>), IntegrationError> {
        let n = self.structure.unknowns();
        let c = self.spacecraft.exhaust_speed;
        let flight = self.fly(z, tolerances, jacobian)?;
        let orbit = orbit_state(&self.scenario.target, Dual2_64::from_re(z[5]).derivative());
        let y = &flight.y_final;
        let mut f = vec![0.0; n];
        for i in 0..4 {
            f[i] = y[idx::R + i] - orbit[i].re;
        }
        f[4] = match self.pin {
            Some(t) => z[6] - t,
            None => (0..4).map(|i| y[idx::LR + i] * orbit[i].v1).sum(),
        };
        f[5] = y[idx::LM];
        for (s, ys) in flight.y_switch.iter().enumerate() {
            f[6 + s] = switching_function(ys, c);
        }
        let mut jac = Vec::new();
        if jacobian {
            jac = vec![vec![0.0; n]; n];
            let g = &flight.dy_final;
            for k in 0..n {
                for i in 0..4 {
                    jac[i][k] = g[k][idx::R + i];
                }
                jac[4][k] = match self.pin {
                    Some(_) => f64::from(u8::from(k == 6)),
                    None => (0..4).map(|i| g[k][idx::LR + i] * orbit[i].v1).sum(),
                };
                jac[5][k] = g[k][idx::LM];
            }
            for i in 0..4 {
                jac[i][5] = -orbit[i].v1;
            }
            if self.pin.is_none() {
                jac[4][5] = (0..4).map(|i| y[idx::LR + i] * orbit[i].v2).sum();
            }
            for (s, (ys, gs)) in flight.y_switch.iter().zip(&flight.dy_switch).enumerate() {
                let grad = rho_gradient(ys, c);
                for k in 0..n {
                    jac[6 + s][k] = (0..Y_LEN).map(|i| grad[i] * gs[k][i]).sum();
                }
            }
        }
        Ok((f, jac))
    }
}

impl<const K: usize> ShootingProblem<K> for BangBangTransfer<'_> {
    fn residual_only(
        &self,
        _eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<SVector<f64, K>, IntegrationError> {
        let (f, _) = self.evaluate(z.as_slice(), tolerances, false)?;
        Ok(SVector::from_column_slice(&f))
    }

    fn residual(
        &self,
        _eps: f64,
        z: &SVector<f64, K>,
        tolerances: &Tolerances,
    ) -> Result<(SVector<f64, K>, SMatrix<f64, K, K>), IntegrationError> {
        let (f, jac) = self.evaluate(z.as_slice(), tolerances, true)?;
        Ok((SVector::from_column_slice(&f), SMatrix::from_fn(|i, k| jac[i][k])))
    }
}

/// The impulsive Hohmann transfer between the two orbits' semi-major axes, turned into finite
/// burns: delta-vs, burn durations and masses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hohmann {
    /// +1 for a raise (prograde burns), -1 for a lowering.
    pub sign: f64,
    /// Impulse magnitudes |dv1|, |dv2| at departure and arrival (AU/t*).
    pub dv: [f64; 2],
    /// Final mass of the impulsive transfer exp(-(dv1 + dv2) / c): an upper bound of the final
    /// mass of any finite-thrust transfer between circular orbits.
    pub final_mass: f64,
    /// Mass after the first burn.
    pub mid_mass: f64,
    /// Durations of the two burns at full thrust.
    pub burn: [f64; 2],
    /// Half period of the transfer ellipse.
    pub half_period: f64,
    /// Exhaust speed c (AU/t*) the masses and burns were computed with.
    pub exhaust_speed: f64,
}

impl Hohmann {
    /// The Hohmann transfer between circles of radii `r1` and `r2` (AU) for spacecraft `sc`.
    pub fn new(r1: f64, r2: f64, sc: &CanonicalSpacecraft) -> Self {
        let c = sc.exhaust_speed;
        let dv1 = ((1.0 / r1).sqrt() * ((2.0 * r2 / (r1 + r2)).sqrt() - 1.0)).abs();
        let dv2 = ((1.0 / r2).sqrt() * (1.0 - (2.0 * r1 / (r1 + r2)).sqrt())).abs();
        let mid_mass = (-dv1 / c).exp();
        let final_mass = mid_mass * (-dv2 / c).exp();
        let flow = sc.thrust / c;
        Self {
            sign: if r2 >= r1 { 1.0 } else { -1.0 },
            dv: [dv1, dv2],
            final_mass,
            mid_mass,
            burn: [(1.0 - mid_mass) / flow, (mid_mass - final_mass) / flow],
            half_period: core::f64::consts::PI * (0.5 * (r1 + r2)).powf(1.5),
            exhaust_speed: c,
        }
    }

    /// The Hohmann transfer between the scenario's departure and target semi-major axes
    /// (eccentricities ignored).
    pub fn of(scenario: &Scenario, sc: &CanonicalSpacecraft) -> Self {
        Self::new(scenario.initial.shape.a, scenario.target.a, sc)
    }

    /// The range of times the centre of the first burn can take (both burns inside the flight).
    pub fn centre_range(&self, tof: f64) -> (f64, f64) {
        (0.5 * self.burn[0], tof - self.half_period - 0.5 * self.burn[1])
    }

    /// Guess of the coast-burn-coast-burn-coast extremal with the first burn centred at `centre`:
    /// on the initial circle the primer is the rotating along-track vector of constant magnitude
    /// m_f / c (rho = 0 there, lambda_m(0) = 1 - m_f), the burns are the Hohmann burns made
    /// finite, and nu_f is where the final circle is reached at tf.
    pub fn guess(&self, scenario: &Scenario, centre: f64) -> [f64; 10] {
        let tof = scenario.time_of_flight();
        let theta0 = scenario.initial.polar().theta;
        let n0 = scenario.initial.shape.a.powf(-1.5);
        let nf = scenario.target.a.powf(-1.5);
        let k = self.final_mass / self.exhaust_speed;
        let (s, c) = theta0.sin_cos();
        let centre2 = centre + self.half_period;
        let theta_f = theta0 + n0 * centre + core::f64::consts::PI + nf * (tof - centre2);
        [
            -self.sign * k * n0 * c,
            -self.sign * k * n0 * s,
            self.sign * k * s,
            -self.sign * k * c,
            1.0 - self.final_mass,
            theta_f - scenario.target.omega,
            centre - 0.5 * self.burn[0],
            centre + 0.5 * self.burn[0],
            centre2 - 0.5 * self.burn[1],
            centre2 + 0.5 * self.burn[1],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::scenario::ScenarioKind;
    use shared::spacecraft::Spacecraft;

    /// The assembled Jacobian (switching times included) against central differences.
    #[test]
    fn structured_jacobian_matches_finite_differences() {
        let sc = Spacecraft::MSR_ERO.canonical().unwrap();
        let scenario = ScenarioKind::TransferCircular.draw(7, 0);
        let tf = scenario.time_of_flight();
        let problem = BangBangTransfer {
            scenario: &scenario,
            spacecraft: sc,
            structure: Structure {
                first: Regime::Coast,
                switches: 4,
            },
            pin: None,
        };
        let c = scenario.initial.cartesian();
        let z = [
            -0.5 * c.r[0],
            -0.5 * c.r[1],
            0.5 * c.r[1],
            -0.5 * c.r[0],
            0.08,
            2.0,
            0.1 * tf,
            0.2 * tf,
            0.5 * tf,
            0.6 * tf,
        ];
        let tol = Tolerances {
            relative: 1e-12,
            absolute: 1e-13,
            ..Tolerances::default()
        };
        let (_, jac) = problem.evaluate(&z, &tol, true).unwrap();
        let h = 1e-6;
        for k in 0..z.len() {
            let (mut zp, mut zm) = (z, z);
            zp[k] += h;
            zm[k] -= h;
            let (fp, _) = problem.evaluate(&zp, &tol, false).unwrap();
            let (fm, _) = problem.evaluate(&zm, &tol, false).unwrap();
            for i in 0..z.len() {
                let fd = (fp[i] - fm[i]) / (2.0 * h);
                assert!(
                    (jac[i][k] - fd).abs() < 1e-6 * (1.0 + fd.abs()),
                    "dF{i}/dz{k}: {} vs {fd}",
                    jac[i][k]
                );
            }
        }
    }
}

//! After construction, the hot calls perform zero heap allocations: proved with a counting
//! global allocator (per thread, so parallel tests do not interfere).

use crate::common;
use crate::counting_alloc::allocations_during;
use pinc::runtime::{BatchWorkspace, HorizonLinearisation, Predictor, Real};
use pinc::traits::DiscreteModel;
use pinc::vehicle::Rk4Vehicle;
use pinc::{Input, InputMatrix, State, StateMatrix};

#[test]
fn predictor_hot_calls_do_not_allocate() {
    hot_calls_do_not_allocate::<f32>();
    hot_calls_do_not_allocate::<f64>();
}

fn hot_calls_do_not_allocate<T: Real>() {
    for (name, model) in common::variants() {
        for portable in [false, true] {
            let mut p = Predictor::<T>::from_model(&model).with_yaw_renormalisation(true);
            if portable {
                p = p.with_portable_kernels();
            }
            let mut ws = p.workspace();
            let mut bws = BatchWorkspace::new(&p);
            let n = 20;
            let x0 = State::from([0.1, 0.2, 0.3, 1.0, 0.0, 0.1, 0.0, 0.05, 0.1]);
            let inputs = vec![Input::new(2.0, 0.1, 5.0, 0.05); n];
            let mut traj = vec![State::zeros(); n + 1];
            let mut lin = HorizonLinearisation::new(n);
            let batch_x0 = vec![x0; 37];
            let batch_inputs = vec![Input::new(1.0, 0.0, 3.0, 0.0); 37 * n];
            let mut batch_out = vec![State::zeros(); 37 * (n + 1)];
            let (mut next, mut a1, mut b1) = (State::zeros(), StateMatrix::zeros(), InputMatrix::zeros());
            let count = allocations_during(|| {
                p.step(&mut ws, &x0, &inputs[0], &mut next).unwrap();
                p.step_dt(&mut ws, &x0, &inputs[0], 0.06, &mut next).unwrap();
                p.rollout(&mut ws, &x0, &inputs, &mut traj).unwrap();
                p.linearise(&mut ws, &x0, &inputs[0], &mut next, &mut a1, &mut b1).unwrap();
                p.linearise_horizon(&mut ws, &x0, &inputs, &mut lin).unwrap();
                p.rollout_batch(&mut bws, &batch_x0, &batch_inputs, &mut batch_out).unwrap();
                // Errors are returned without allocating too.
                let bad = State::from_element(f64::NAN);
                assert!(p.step(&mut ws, &bad, &inputs[0], &mut next).is_err());
                std::hint::black_box(ws.envelope_status());
            });
            assert_eq!(count, 0, "{name} (portable {portable}) allocated {count} times");
        }
    }
}

#[test]
fn analytic_vehicle_hot_calls_do_not_allocate() {
    let v = Rk4Vehicle::default();
    #[allow(clippy::let_unit_value)] // the analytic model's workspace is ()
    let mut ws = DiscreteModel::workspace(&v);
    let n = 20;
    let x0 = State::from([0.1, 0.2, 0.3, 1.0, 0.0, 0.1, 0.0, 0.05, 0.1]);
    let inputs = vec![Input::new(2.0, 0.1, 5.0, 0.05); n];
    let mut lin = HorizonLinearisation::new(n);
    let mut next = State::zeros();
    let count = allocations_during(|| {
        DiscreteModel::step(&v, &mut ws, &x0, &inputs[0], &mut next).unwrap();
        v.linearise_horizon(&mut ws, &x0, &inputs, &mut lin).unwrap();
    });
    assert_eq!(count, 0);
}

/// The state estimator's sample (queued measurements, reported inputs, prediction through the
/// model's exact Jacobians, updates) allocates nothing once started, on the network and on
/// the analytic vehicle.
#[test]
fn estimator_samples_do_not_allocate() {
    use pinc::estimation::{Estimator, Measurement, NoiseSettings};
    fn check<M: DiscreteModel>(name: &str, model: M) {
        let mut tr = Estimator::new(model, NoiseSettings::default());
        let feed = |tr: &mut Estimator<M>, t: f64| {
            // A changing reading: an exact repeat is left out before it is queued.
            tr.measure(Measurement::Depth { t, z: 1.0 + 0.01 * (10.0 * t).sin() });
            tr.measure(Measurement::Heading { t, psi: 0.3 });
            tr.measure(Measurement::YawRate { t, r: 0.01 });
            tr.measure(Measurement::VelocityNed { t, vn: 0.1, ve: 0.0, vd: 0.0 });
            tr.applied(t - 0.02, Input::new(5.0, 0.0, 10.0, 0.2));
        };
        feed(&mut tr, 0.0);
        assert!(tr.advance(0.0).unwrap().is_some());
        let mut t = 0.0;
        let count = allocations_during(|| {
            for _ in 0..50 {
                t += 0.08;
                feed(&mut tr, t);
                tr.commanded(Input::new(5.0, 0.0, 10.0, 0.2));
                std::hint::black_box(tr.advance(t).unwrap());
            }
        });
        assert_eq!(count, 0, "{name}: the estimator allocated {count} times in 50 samples");
    }
    for (name, model) in common::variants() {
        check(name, Predictor::<f64>::from_model(&model));
    }
    check("analytic", Rk4Vehicle::default());
}

/// A control cycle on the Riccati solver (rollout, Jacobians, the QP's data, the interior-point
/// iterations, the plan) allocates nothing once the controller is built: on the analytic
/// vehicle and on a network with soft envelope bounds, with and without rate limits.
#[cfg(feature = "mpc")]
#[test]
fn riccati_mpc_cycles_do_not_allocate() {
    use pinc::mpc::{Mpc, MpcConfig, QpSolver, Reference};
    fn check<M: DiscreteModel + Clone>(name: &str, model: M, bounds: (Input, Input)) {
        for rate_limit in [None, Some([2.0, 2.0, 5.0, 0.5])] {
            let cfg = MpcConfig { qp: QpSolver::Riccati, bounds: Some(bounds), rate_limit, ..MpcConfig::default() };
            let mut mpc = Mpc::new(model.clone(), cfg).unwrap();
            let x = State::from([0.1, 0.2, 0.3, 1.0, 0.0, 0.1, 0.0, 0.05, 0.1]);
            let refs = [Reference::depth_heading(1.0, 0.5); 20];
            mpc.step(&x, &refs);
            let mut solved = 0;
            let count = allocations_during(|| {
                for _ in 0..10 {
                    let report = mpc.step(&x, &refs);
                    solved += usize::from(report.fallback.is_none());
                }
            });
            assert_eq!(count, 0, "{name} (rate limit {rate_limit:?}) allocated {count} times in 10 cycles");
            assert_eq!(solved, 10, "{name}: every cycle solved");
        }
    }
    let bounds = (Input::new(-40.0, -40.0, -40.0, -10.0), Input::new(40.0, 40.0, 40.0, 10.0));
    check("analytic", Rk4Vehicle::default(), bounds);
    for (name, model) in common::variants() {
        let p = Predictor::<f64>::from_model(&model);
        let b = p.input_bounds().unwrap_or(bounds);
        check(name, p, b);
    }
}

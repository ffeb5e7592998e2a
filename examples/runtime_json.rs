//! Prints what the runtime computes for one model, as JSON with every number to full
//! precision (shortest round-trip): a step, a 50-step rollout and the horizon linearisation
//! (trajectory, every A_k and B_k), by the `f32` predictor on the portable kernels, the `f32`
//! predictor as dispatched on this CPU (AVX2 + FMA where x86 has them) and the `f64` reference.
//!
//! `python/tests/test_cross_platform.py` runs it natively and under qemu (the ARM builds of
//! `scripts/cross_build.sh`) and compares the numbers.
//!
//! ```sh
//! cargo run --release --example runtime_json -- [models/mpc_pinc_thrust.pinc] > x86.json
//! ```

use pinc::model::PincModel;
use pinc::runtime::{HorizonLinearisation, Predictor, Real};
use pinc::{Input, State};
use serde_json::{Value, json};

/// Steps in the rollout and the linearised horizon.
const STEPS: usize = 50;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).unwrap_or_else(|| "models/mpc_pinc_thrust.pinc".into());
    let model = PincModel::load(&path)?;
    // A dive with a turn, every input varying (the heave force about the force at rest).
    let x0 = State::from([0.3, -0.2, 0.5, 0.3f64.cos(), 0.3f64.sin(), 0.2, 0.02, 0.05, 0.03]);
    let inputs: Vec<Input> = (0..STEPS)
        .map(|k| {
            let t = k as f64 * model.dt;
            Input::new(4.0 * (0.7 * t).sin(), 1.5 * (0.4 * t).cos(), 8.0 + 6.0 * (0.9 * t).sin(), 0.4 * (0.5 * t).sin())
        })
        .collect();
    let runs = json!({
        "f32_portable": run(&Predictor::new(&model).with_portable_kernels(), &x0, &inputs)?,
        "f32_dispatched": run(&Predictor::new(&model), &x0, &inputs)?,
        "f64_reference": run(&Predictor::reference(&model).with_portable_kernels(), &x0, &inputs)?,
    });
    let out = json!({
        "arch": std::env::consts::ARCH,
        "avx2_fma": avx2_fma(),
        "model": path,
        "steps": STEPS,
        "runs": runs,
    });
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

/// Step, rollout and linearisation by one predictor.
fn run<T: Real>(p: &Predictor<T>, x0: &State, inputs: &[Input]) -> Result<Value, Box<dyn std::error::Error>> {
    let mut ws = p.workspace();
    let mut next = State::zeros();
    p.step(&mut ws, x0, &inputs[0], &mut next)?;
    let mut rollout = vec![State::zeros(); inputs.len() + 1];
    p.rollout(&mut ws, x0, inputs, &mut rollout)?;
    let rollout_exits = ws.envelope_status().exits;
    let mut lin = HorizonLinearisation::new(inputs.len());
    p.linearise_horizon(&mut ws, x0, inputs, &mut lin)?;
    let matrix = |m: &dyn Fn(usize, usize) -> f64, rows: usize, cols: usize| -> Value {
        (0..rows).map(|i| (0..cols).map(|j| m(i, j)).collect::<Vec<_>>()).collect()
    };
    Ok(json!({
        "step": next.as_slice(),
        "rollout": rollout.iter().map(|x| x.as_slice().to_vec()).collect::<Vec<_>>(),
        "rollout_envelope_exits": rollout_exits,
        "trajectory": lin.trajectory().iter().map(|x| x.as_slice().to_vec()).collect::<Vec<_>>(),
        "a": lin.a().iter().map(|a| matrix(&|i, j| a[(i, j)], a.nrows(), a.ncols())).collect::<Vec<_>>(),
        "b": lin.b().iter().map(|b| matrix(&|i, j| b[(i, j)], b.nrows(), b.ncols())).collect::<Vec<_>>(),
    }))
}

fn avx2_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

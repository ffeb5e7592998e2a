//! The tensor right-hand side against the vehicle module, and weight export round trips.

use super::*;
use crate::model::{Architecture, PincModel, Provenance};
use crate::types::{Input, State};
use crate::vehicle::{self, VehicleParams};
use burn::prelude::*;

fn batch(rows: &[[f64; 9]], device: &Device) -> Tensor<2> {
    let flat: Vec<f32> = rows.iter().flat_map(|r| r.iter().map(|&v| v as f32)).collect();
    Tensor::from_data(TensorData::new(flat, [rows.len(), 9]), device)
}

#[test]
fn tensor_rhs_matches_the_vehicle_model() {
    let device = Device::flex();
    let p = VehicleParams::default();
    let states = [
        [0.3, -0.1, 1.2, 0.8, 0.6, 0.4, -0.15, 0.2, -0.3],
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [-2.0, 1.0, 0.5, -0.6, -0.8, -0.5, 0.25, -0.3, 0.5],
    ];
    let inputs = [[3.0, -1.0, 6.0, 0.2], [0.0, 0.0, 0.0, 0.0], [-10.0, 5.0, 20.0, -1.0]];
    let x = batch(&states, &device);
    let uflat: Vec<f32> = inputs.iter().flat_map(|r| r.iter().map(|&v| v as f32)).collect();
    let u = Tensor::<2>::from_data(TensorData::new(uflat, [3, 4]), &device);
    let got = net::to_f32(rhs(&p, x, u));
    for (i, (s, f)) in states.iter().zip(&inputs).enumerate() {
        let want = vehicle::rhs(&p, &State::from(*s), &Input::from(*f));
        for k in 0..9 {
            let g = f64::from(got[i * 9 + k]);
            assert!((g - want[k]).abs() <= 1e-5 * want[k].abs().max(1.0), "row {i} component {k}: {g} vs {}", want[k]);
        }
    }
}

#[test]
fn exported_weights_round_trip_through_the_frozen_format() {
    let device = Device::flex();
    let arch = Architecture::paper(4, 32);
    let net = PincNet::init(&arch, 7, &device);
    let model = PincModel {
        architecture: arch.clone(),
        dt: 0.08,
        input_scaling: None,
        output_scaling: None,
        envelope: None,
        provenance: Provenance::default(),
        weights: net.weights(),
        vehicle: crate::vehicle::VehicleParams::default(),
    };
    crate::model::validate(&model).unwrap();
    let again = PincNet::from_model(&model, &device);
    assert_eq!(again.weights(), model.weights);
    // Xavier bounds and the documented initial values.
    let w0 = &model.weights.hidden[0];
    let limit = (6.0 / (14.0 + 32.0_f64)).sqrt() as f32;
    assert!(w0.linear.weight.iter().all(|w| w.abs() <= limit));
    assert!(w0.linear.bias.iter().all(|b| *b == 0.0) && w0.beta == 1.0);
    // Seeded: the same seed gives the same weights, another seed others.
    assert_eq!(PincNet::init(&arch, 7, &device).weights(), model.weights);
    assert_ne!(PincNet::init(&arch, 8, &device).weights(), model.weights);
}

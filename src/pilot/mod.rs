//! Flying with the pilot: the sticks (from a gamepad on pinc's page, a ground station's
//! joystick or a script) as velocity references for the MPC, and the stop it plans when they
//! are let go, so a released stick comes to rest without going past and coming back
//! (docs/PILOT.md, docs/MODEL.md section 14). The live session flies it on the vehicle
//! (`mpc_track --connect --pilot`), [`fly_simulated`] on the simulated one.

mod assist;
mod sticks;

pub use assist::{DEADBAND, DEADMAN_S, Phase, PhaseChange, Phases, PilotAssist, STOP_TIMEOUT_S};
pub use sticks::{AXES, STEADY_SPEED_SHARE, StickError, StickLimits, Sticks};

use crate::closed_loop::{Plant, Sample, run_with};
use crate::mpc::Mpc;
use crate::traits::DiscreteModel;

/// The pilot's sticks flown on the simulated `plant` for `duration` s from rest at the
/// surface: `sticks(t)` is the reading at `t` (`None`: nothing sent then, as a page gone
/// quiet). The samples record the true state and the assist's reference at each.
pub fn fly_simulated<M: DiscreteModel>(
    mpc: &mut Mpc<M>,
    assist: &mut PilotAssist,
    plant: &Plant,
    duration: f64,
    mut sticks: impl FnMut(f64) -> Option<Sticks>,
) -> Vec<Sample> {
    let dt = mpc.model().dt();
    let position = mpc.config().tracks_position();
    let references = |t: f64, x: &crate::types::State, refs: &mut [crate::mpc::Reference]| {
        if let Some(s) = sticks(t) {
            // A script's readings are checked as a page's are; a refused one holds.
            let _ = assist.take(t, Ok(s));
        }
        assist.references(t, x, position, dt, refs)
    };
    run_with(mpc, duration, plant, |s| *s, references, |_| true)
}

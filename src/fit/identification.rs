//! Stage 2, the identification: the vehicle identified on the train split, surge and sway
//! kept from the starting file where no position source was fused. Apart because both the
//! first pass and every later one identify the same way.

use super::{FitError, Pipeline, report};
use crate::dataset::Dataset;
use crate::identify::{Identification, identify};
use crate::vehicle::VehicleParams;

/// The value of coefficient `key` of `p` (0 for a name it does not have).
pub(crate) fn coefficient(p: &VehicleParams, key: &str) -> f64 {
    p.named().into_iter().find(|(k, _)| *k == key).map_or(0.0, |(_, v)| v)
}

impl Pipeline<'_> {
    /// The vehicle identified on the train split; surge and sway kept from the starting file
    /// without a position source.
    pub(super) fn identify_on(&self, data: &Dataset, horizontal: bool) -> Result<Identification, FitError> {
        let train_set = data.set("train").filter(|s| s.count > 0).ok_or_else(|| {
            FitError::Data("the train split is empty: the recordings are too short for one window".into())
        })?;
        let mut id = identify(&[train_set], &self.base).map_err(|e| FitError::Data(format!("identification: {e}")))?;
        if !horizontal {
            // Without a position source the estimated surge and sway are the starting file's
            // own motion: a fit of them would echo it, so they stay the starting file's...
            for &k in report::AXES[..2].iter().flat_map(|(_, keys)| keys.iter()) {
                if let Some(slot) = id.vehicle.get_mut(k) {
                    *slot = coefficient(&self.base, k);
                }
            }
            // ...but for their added masses, made equal: their difference turns the yaw into
            // surge and sway and back (the Coriolis terms and the Munk moment), a coupling the
            // recordings cannot confirm. On ArduSub's simulator (no added mass) the fitted file
            // with the BlueROV2's -2.6 and -18.5 held the heading to 0.81 deg as the controller's
            // model, and to 0.57 with them equal (its own file: 0.52).
            let mean = 0.5 * (self.base.x_ud + self.base.y_vd);
            (id.vehicle.x_ud, id.vehicle.y_vd) = (mean, mean);
        }
        Ok(id)
    }
}

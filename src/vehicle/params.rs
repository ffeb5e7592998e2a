//! BlueROV2 parameters of the simplified 4-DOF Fossen model (docs/MODEL.md section 1).

use serde::{Deserialize, Serialize};

/// Rigid-body, added-mass and damping coefficients of the vehicle.
///
/// Every field is public so any coefficient can be overridden; [`Default`] gives the
/// BlueROV2 values of the paper's public implementation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VehicleParams {
    /// Mass (kg). Default: 11.4
    pub m: f64,
    /// Gravity (m/s^2). Default: 9.82
    pub g: f64,
    /// Water density (kg/m^3). Default: 1026
    pub rho: f64,
    /// Displaced volume (m^3). Default: 0.0115
    pub volume: f64,
    /// Surge added mass (kg). Default: -2.6
    pub x_ud: f64,
    /// Sway added mass (kg). Default: -18.5
    pub y_vd: f64,
    /// Heave added mass (kg). Default: -13.3
    pub z_wd: f64,
    /// Yaw added inertia (kg m^2). Default: -0.28
    pub n_rd: f64,
    /// Yaw inertia (kg m^2). Default: 0.245
    pub izz: f64,
    /// Linear surge damping (N s/m). Default: -0.09
    pub x_u: f64,
    /// Linear sway damping (N s/m). Default: -0.26
    pub y_v: f64,
    /// Linear heave damping (N s/m). Default: -0.19
    pub z_w: f64,
    /// Linear yaw damping (N m s/rad). Default: -4.64
    pub n_r: f64,
    /// Quadratic surge damping (N s^2/m^2). Default: -34.96
    pub x_uu: f64,
    /// Quadratic sway damping (N s^2/m^2). Default: -103.25
    pub y_vv: f64,
    /// Quadratic heave damping (N s^2/m^2). Default: -74.23
    pub z_ww: f64,
    /// Quadratic yaw damping (N m s^2/rad^2). Default: -0.43
    pub n_rr: f64,
}

impl Default for VehicleParams {
    fn default() -> Self {
        Self {
            m: 11.4,
            g: 9.82,
            rho: 1026.0,
            volume: 0.0115,
            x_ud: -2.6,
            y_vd: -18.5,
            z_wd: -13.3,
            n_rd: -0.28,
            izz: 0.245,
            x_u: -0.09,
            y_v: -0.26,
            z_w: -0.19,
            n_r: -4.64,
            x_uu: -34.96,
            y_vv: -103.25,
            z_ww: -74.23,
            n_rr: -0.43,
        }
    }
}

impl VehicleParams {
    /// Weight minus buoyancy, `m g - rho V g` (N); negative means the vehicle rises.
    pub fn net_buoyancy(&self) -> f64 {
        self.m * self.g - self.rho * self.volume * self.g
    }

    /// Scales every damping coefficient (linear and quadratic) by `factor`, e.g. 1.2 for +20 %.
    pub fn with_damping_scaled(mut self, factor: f64) -> Self {
        for d in [
            &mut self.x_u,
            &mut self.y_v,
            &mut self.z_w,
            &mut self.n_r,
            &mut self.x_uu,
            &mut self.y_vv,
            &mut self.z_ww,
            &mut self.n_rr,
        ] {
            *d *= factor;
        }
        self
    }
}

/// Speed `s >= 0` at which a force `f >= 0` balances damping `lin s + quad s^2` (both
/// coefficients negative, as in Fossen's convention): the positive root of
/// `f + lin s + quad s |s| = 0`.
pub fn terminal_speed(f: f64, lin: f64, quad: f64) -> f64 {
    let (a, b) = (-quad, -lin);
    if a == 0.0 {
        return f / b;
    }
    (-b + (b * b + 4.0 * a * f).sqrt()) / (2.0 * a)
}

/// What makes a set of coefficients unusable as a vehicle model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamsError {
    /// A coefficient is NaN or infinite.
    #[error("{key} = {value} is not finite")]
    NotFinite {
        /// The coefficient's name (the `VehicleParams` field).
        key: &'static str,
        /// Its value.
        value: f64,
    },
    /// A coefficient that makes the model meaningless.
    #[error("{key} = {value}: {why}")]
    Meaningless {
        /// The coefficient's name.
        key: &'static str,
        /// Its value.
        value: f64,
        /// What it breaks.
        why: &'static str,
    },
}

impl VehicleParams {
    /// Every coefficient with its name, in declaration order (the names of a vehicle file).
    pub fn named(&self) -> [(&'static str, f64); 17] {
        [
            ("m", self.m),
            ("g", self.g),
            ("rho", self.rho),
            ("volume", self.volume),
            ("x_ud", self.x_ud),
            ("y_vd", self.y_vd),
            ("z_wd", self.z_wd),
            ("n_rd", self.n_rd),
            ("izz", self.izz),
            ("x_u", self.x_u),
            ("y_v", self.y_v),
            ("z_w", self.z_w),
            ("n_r", self.n_r),
            ("x_uu", self.x_uu),
            ("y_vv", self.y_vv),
            ("z_ww", self.z_ww),
            ("n_rr", self.n_rr),
        ]
    }

    /// The coefficient called `key`, to set; `None` for a name that is not one.
    pub fn get_mut(&mut self, key: &str) -> Option<&mut f64> {
        Some(match key {
            "m" => &mut self.m,
            "g" => &mut self.g,
            "rho" => &mut self.rho,
            "volume" => &mut self.volume,
            "x_ud" => &mut self.x_ud,
            "y_vd" => &mut self.y_vd,
            "z_wd" => &mut self.z_wd,
            "n_rd" => &mut self.n_rd,
            "izz" => &mut self.izz,
            "x_u" => &mut self.x_u,
            "y_v" => &mut self.y_v,
            "z_w" => &mut self.z_w,
            "n_r" => &mut self.n_r,
            "x_uu" => &mut self.x_uu,
            "y_vv" => &mut self.y_vv,
            "z_ww" => &mut self.z_ww,
            "n_rr" => &mut self.n_rr,
            _ => return None,
        })
    }

    /// Refuses coefficients that make the model meaningless: non-finite values, a
    /// non-positive mass, gravity, density or volume, a non-positive effective mass or
    /// inertia (`m - x_ud`, `m - y_vd`, `m - z_wd`, `izz - n_rd`), positive damping (which
    /// would feed energy in; Fossen's convention makes damping coefficients <= 0).
    ///
    /// # Errors
    /// The first offending coefficient, by name.
    pub fn validate(&self) -> Result<(), ParamsError> {
        for (key, value) in self.named() {
            if !value.is_finite() {
                return Err(ParamsError::NotFinite { key, value });
            }
        }
        let bad = |key, value, why| Err(ParamsError::Meaningless { key, value, why });
        for (key, value) in
            [("m", self.m), ("g", self.g), ("rho", self.rho), ("volume", self.volume), ("izz", self.izz)]
        {
            if value <= 0.0 {
                return bad(key, value, "must be positive");
            }
        }
        for (key, added, rigid) in [
            ("x_ud", self.x_ud, self.m),
            ("y_vd", self.y_vd, self.m),
            ("z_wd", self.z_wd, self.m),
            ("n_rd", self.n_rd, self.izz),
        ] {
            if rigid - added <= 0.0 {
                return bad(key, added, "the effective mass or inertia (rigid minus added) must be positive");
            }
        }
        for (key, value) in self.named().into_iter().skip(9) {
            if value > 0.0 {
                return bad(
                    key,
                    value,
                    "positive damping feeds energy into the vehicle (damping coefficients are <= 0)",
                );
            }
        }
        Ok(())
    }
}

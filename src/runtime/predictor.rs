//! The frozen PINC as an immutable [`Predictor`] (the network in the layout the kernels
//! want, what its output means, its sample period and its training envelope) and the
//! per-thread [`Workspace`] its calls compute in.

use super::envelope::{EnvelopeCheck, EnvelopeStatus};
use super::error::{RuntimeError, check_input, check_state};
use super::kernels::{Avx2Fma, MulAdd, NetOut, NetScratch, Network, Portable, Real};
use super::output_map::OutputMap;
use crate::model::{Envelope, PincModel};
use crate::types::{Input, State};
use crate::vehicle::Rk4Vehicle;

/// A frozen PINC ready to run: `x_hat(t) = x + N([x_seen, u, t])` with the planar
/// increments rotated by the predicted yaw (docs/MODEL.md section 3); or a hybrid model,
/// `x_hat(t) = Phi_t(x, u) + N([x_seen, u, t])`, `Phi_t` being the file's vehicle integrated
/// over `t` (section 13). Both kinds run through the same calls.
///
/// Immutable after construction; every call takes a [`Workspace`] so that one predictor
/// can serve many threads.
///
/// `T` is the precision of the network arithmetic: `f32` (the default, [`Predictor::new`])
/// is the fast path and the precision the network was trained in; `f64`
/// ([`Predictor::reference`]) is the reference whose Jacobians are checked against finite
/// differences. States, inputs and Jacobians are `f64` either way, and the residual and
/// rotation are applied in `f64`.
///
/// # Example
/// Load the shipped controller model, predict one step and linearise a 20-step horizon:
/// ```
/// use pinc::model::PincModel;
/// use pinc::runtime::{HorizonLinearisation, Predictor};
/// use pinc::{Input, State};
///
/// let model = PincModel::load(concat!(env!("CARGO_MANIFEST_DIR"), "/models/mpc_pinc.pinc"))?;
/// let p = Predictor::new(&model);
/// let mut ws = p.workspace();
/// // At rest, heading 0 ((cos, sin) = (1, 0)), pushing forward with 5 N.
/// let x = State::from([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
/// let u = Input::new(5.0, 0.0, 0.0, 0.0);
/// let mut next = State::zeros();
/// p.step(&mut ws, &x, &u, &mut next)?;
/// assert!(next[5] > 0.0, "surge speeds up");
///
/// let mut lin = HorizonLinearisation::new(20);
/// p.linearise_horizon(&mut ws, &x, &[u; 20], &mut lin)?;
/// assert_eq!(lin.trajectory()[1], next);
/// assert!(lin.b()[0][(5, 0)] > 0.0, "d u_1 / d X");
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug, Clone)]
pub struct Predictor<T: Real = f32> {
    pub(crate) net: Network<T>,
    pub(crate) output: OutputMap,
    pub(crate) dt: f64,
    pub(crate) envelope: EnvelopeCheck,
    /// A hybrid model's analytic part, whose step the network's output is added to
    /// (docs/MODEL.md section 13); in `f64` whatever `T` is.
    pub(crate) physics: Option<Rk4Vehicle>,
    /// A hybrid whose correction is anchored at rest: the network's output at rest over the
    /// model's own period, subtracted from every output (other periods compute theirs).
    pub(crate) rest: Option<(f64, NetOut)>,
    /// The input at rest (the heave force that holds the vehicle still).
    pub(crate) rest_input: Input,
    /// A hybrid whose correction is zero ([`PincModel::correction_is_zero`]): its physics
    /// everywhere, the training envelope no bound on where it may be used.
    pub(crate) physics_only: bool,
    /// Set where the CPU has AVX2 + FMA and the portable kernels were not asked for.
    pub(crate) cpu: Option<Avx2Fma>,
}

impl Predictor {
    /// Builds the default (`f32`) predictor from a validated model.
    ///
    /// # Memory allocation
    /// Allocates the weights twice (two layouts), about `8 * parameters` bytes.
    pub fn new(model: &PincModel) -> Self {
        Self::from_model(model)
    }
}

impl Predictor<f64> {
    /// Builds the `f64` reference predictor: the same network computed in double precision,
    /// about 2.5x slower, whose Jacobians the tests check against finite differences.
    ///
    /// # Memory allocation
    /// Allocates the weights twice (two layouts), about `16 * parameters` bytes.
    pub fn reference(model: &PincModel) -> Self {
        Self::from_model(model)
    }
}

impl<T: Real> Predictor<T> {
    /// Builds a predictor computing in `T` from a validated model (for code generic over the
    /// precision; [`Predictor::new`] and [`Predictor::reference`] name the two).
    ///
    /// # Memory allocation
    /// Allocates the weights twice (two layouts, padded to whole packs of 8 units),
    /// about `2 * size_of::<T>() * parameters` bytes.
    pub fn from_model(model: &PincModel) -> Self {
        let a = &model.architecture;
        let net = Network::new(model);
        let mut p = Self {
            envelope: EnvelopeCheck::new(model.envelope.clone(), &net.seen),
            net,
            output: OutputMap { residual: a.residual, rotate: a.rotate_xy, renormalise_yaw: true },
            dt: model.dt,
            physics: model.hybrid_vehicle(),
            rest: None,
            rest_input: model.rest_input(),
            physics_only: model.correction_is_zero(),
            cpu: Avx2Fma::detect(),
        };
        if model.hybrid.is_some_and(|h| h.rest_anchored) {
            let mut scratch = NetScratch::new(&p.net);
            let out = p.net.forward::<Portable>(None, &mut scratch, &State::zeros(), &p.rest_input, p.dt, false);
            p.rest = Some((p.dt, out));
        }
        p
    }

    /// A hybrid's output at rest over a step of `dt`, where its correction is anchored there
    /// (what every output is taken relative to); `None` otherwise. Computed in `scratch`
    /// unless `dt` is the model's own period.
    #[inline(always)]
    pub(crate) fn rest_output<F: MulAdd>(&self, scratch: &mut NetScratch<T>, dt: f64) -> Option<NetOut> {
        let (own_dt, own) = self.rest?;
        if dt == own_dt {
            return Some(own);
        }
        Some(self.net.forward::<F>(self.cpu, scratch, &State::zeros(), &self.rest_input, dt, false))
    }

    /// Rescale the predicted `(cos psi, sin psi)` to unit length after every step (with its
    /// exact Jacobian). Default: on, so a rollout's heading vector stays a heading; `false`
    /// gives the bare network, what PyTorch computes (to reproduce the paper's numbers).
    /// Either way a raw prediction off the circle by more than
    /// [`HEADING_TOLERANCE`](super::HEADING_TOLERANCE) is counted in
    /// [`EnvelopeStatus::heading_off_circle`].
    #[must_use]
    pub fn with_yaw_renormalisation(mut self, on: bool) -> Self {
        self.output.renormalise_yaw = on;
        self
    }

    /// Use the portable kernels even where AVX2 + FMA are available (for comparison).
    #[must_use]
    pub fn with_portable_kernels(mut self) -> Self {
        self.cpu = None;
        self
    }

    /// Whether the AVX2 + FMA kernels are in use.
    pub fn uses_fused_kernels(&self) -> bool {
        self.cpu.is_some()
    }

    /// The sample period the model was trained for (s).
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// The training envelope, if the model file has one.
    pub fn envelope(&self) -> Option<&Envelope> {
        self.envelope.envelope()
    }

    /// Whether this is a hybrid model (the vehicle's step plus the network's correction).
    pub fn is_hybrid(&self) -> bool {
        self.physics.is_some()
    }

    /// Whether this is a hybrid whose correction is zero: its physics alone.
    pub fn is_physics_only(&self) -> bool {
        self.physics_only
    }

    /// A hybrid model's physics: its vehicle and RK4 sub-steps over the model's period.
    pub fn hybrid_vehicle(&self) -> Option<&Rk4Vehicle> {
        self.physics.as_ref()
    }

    /// Indices of the 9-state components the network sees.
    pub fn state_inputs(&self) -> &[usize] {
        &self.net.seen
    }

    /// A workspace sized for this predictor.
    pub fn workspace(&self) -> Workspace<T> {
        Workspace::new(self)
    }

    /// Refuses non-finite arguments; records envelope exits.
    #[inline(always)]
    pub(crate) fn check_args(
        &self,
        ws: &mut Workspace<T>,
        step: usize,
        x: &State,
        u: &Input,
    ) -> Result<(), RuntimeError> {
        check_state(step, x)?;
        check_input(step, u)?;
        self.envelope.check(&mut ws.envelope, step, x, u);
        Ok(())
    }
}

/// Scratch memory for one thread's calls into a [`Predictor`].
///
/// # Memory allocation
/// `Workspace::new` allocates about `(3 L + 1 + 2 * 9) * width + inputs + L` floats for `L`
/// hidden layers (widths rounded up to packs of 8); no call that takes a workspace
/// allocates afterwards.
#[derive(Debug, Clone)]
pub struct Workspace<T: Real = f32> {
    /// The network's buffers.
    pub(crate) net: NetScratch<T>,
    /// Envelope exits of the last call.
    pub(crate) envelope: EnvelopeStatus,
}

impl<T: Real> Workspace<T> {
    /// Sizes every buffer for `p`.
    pub fn new(p: &Predictor<T>) -> Self {
        Self { net: NetScratch::new(&p.net), envelope: EnvelopeStatus::default() }
    }

    /// Envelope exits seen during the last `step`, `rollout` or linearisation call.
    pub fn envelope_status(&self) -> EnvelopeStatus {
        self.envelope
    }

    /// Refuses a workspace sized for another network (its buffers would be too small or
    /// laid out for other widths), then clears the envelope record for a new call.
    #[inline(always)]
    pub(crate) fn start_call(&mut self, p: &Predictor<T>) -> Result<(), RuntimeError> {
        if self.net.shape != p.net.shape() {
            return Err(RuntimeError::WorkspaceMismatch { what: "workspace" });
        }
        // Only when something was recorded: the record is larger than a step's arithmetic.
        if !self.envelope.is_clear() {
            self.envelope = EnvelopeStatus::default();
        }
        Ok(())
    }
}

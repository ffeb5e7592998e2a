//! What can stop a controller from being built.

/// What the controller could not do.
#[derive(Debug, thiserror::Error)]
pub enum MpcError {
    /// Neither the configuration nor the model gives input bounds.
    #[error("no input bounds: the model has no training envelope and the configuration sets none")]
    NoBounds,
    /// A configuration value is unusable.
    #[error("invalid MPC configuration: {0}")]
    Config(String),
    /// Clarabel refused the problem at setup.
    #[error("QP setup failed: {0}")]
    Setup(String),
}

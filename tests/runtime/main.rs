//! The frozen-model runtime: behaviour against plain references, exact Jacobians against
//! finite differences, no allocation in the hot calls, and agreement with PyTorch.

#[path = "../common/mod.rs"]
mod common;

mod behaviour;
mod jacobian_fd;
mod no_alloc;
mod torch_fixtures;

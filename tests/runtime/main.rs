//! The frozen-model runtime: behaviour against plain references, exact Jacobians against
//! finite differences, no allocation in the hot calls, and agreement with PyTorch.

#[path = "../common/mod.rs"]
mod common;
#[path = "../common/counting_alloc.rs"]
mod counting_alloc;

mod behaviour;
mod hybrid;
mod jacobian_fd;
mod no_alloc;
mod torch_fixtures;

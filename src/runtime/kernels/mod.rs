//! The numeric kernels under the predictor: vectors in packs of eight and their products,
//! the two precisions, the activations, the network with its affine maps folded into the
//! layers, its forward and reverse passes, and the AVX2 register forward pass. Nothing here
//! knows of predictors, workspaces or envelopes.

mod activation;
mod cpu;
mod fold;
mod forward;
mod network;
mod packs;
mod real;
#[cfg(target_arch = "x86_64")]
mod registers;
#[cfg(test)]
mod tests;

pub use activation::SOFTPLUS_THRESHOLD;
pub(crate) use activation::activate;
pub(crate) use cpu::Avx2Fma;
pub(crate) use fold::Dense;
pub(crate) use network::{NetOut, NetScratch, Network, Shape};
#[cfg(any(target_arch = "x86", target_arch = "x86_64", test))]
pub(crate) use packs::Fused;
pub(crate) use packs::{MulAdd, PACK, Pack, Portable, block_packs, matvec, matvec_rows, packs};
pub use real::Real;

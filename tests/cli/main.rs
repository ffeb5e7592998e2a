//! The `pinc` command line: CSV contracts, exit codes and one-line errors.
#![cfg(feature = "tools")]

mod commands;
mod eval_vehicle;
mod fit;
mod own_vehicle;

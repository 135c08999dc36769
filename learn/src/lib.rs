//! `learn`: the GarNet family of networks (GarNet++ paper) in burn.
//!
//! This crate will hold the models (GarNet-Naive, -Global, -Local, -Global-Params), their
//! losses, training with checkpoints and inference, generic over the burn backend. It is
//! empty until the dataset it trains on exists; see ARCHITECTURE.md for the plan of the
//! workspace.
#![warn(missing_docs)]

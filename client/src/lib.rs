//! lanealign client side: the command-line tools' building blocks (map loading, offline
//! correction, evaluation).

pub mod kitti;
pub mod maps;

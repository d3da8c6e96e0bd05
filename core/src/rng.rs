//! A small deterministic generator (64-bit LCG): the same numbers on every machine and in every
//! version, for data made from a fixed seed: the unit tests' data, the synthetic town's odometry
//! and the simulated drives of [`crate::metrics::Calibration::if_exact`]. Written here because a
//! generator crate promises neither (`rand`'s `StdRng` may change between versions) and these
//! dozen lines are all that is needed; not for cryptography.

/// The generator; the `u64` is its state (the seed).
pub struct Lcg(pub u64);

impl Lcg {
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-12), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

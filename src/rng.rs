//! The small deterministic random generator (SplitMix64) used by the scene generator and by
//! tests: fixed streams from a seed, no dependency, below every module that needs one; and the
//! fast hasher for keys we generate ourselves.

/// A small multiplicative hasher for keys we generate ourselves (tile ids, grid cells): the
/// binning loop and the per-point cell maps look keys up per point, and SipHash's DoS
/// resistance buys nothing there. Not for keys from input files' text.
#[derive(Default, Clone, Copy)]
pub struct FastHasher(u64);

impl std::hash::Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(*b as u64);
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_i64(&mut self, v: i64) {
        self.write_u64(v as u64);
    }
    fn write_usize(&mut self, v: usize) {
        self.write_u64(v as u64);
    }
    fn write_u32(&mut self, v: u32) {
        self.write_u64(v as u64);
    }
    fn write_u8(&mut self, v: u8) {
        self.write_u64(v as u64);
    }
}

/// A `HashMap` with [`FastHasher`].
pub type FastMap<K, V> = std::collections::HashMap<K, V, std::hash::BuildHasherDefault<FastHasher>>;

/// A `HashSet` with [`FastHasher`].
pub type FastSet<K> = std::collections::HashSet<K, std::hash::BuildHasherDefault<FastHasher>>;

/// SplitMix64 generator with Box–Muller normals.
pub struct Rng(pub u64);

impl Rng {
    /// Next 64 random bits. (A generator, not an iterator: the stream never ends, and
    /// callers draw from it through several methods.)
    #[allow(clippy::should_implement_trait)]
    #[inline]
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    #[inline]
    pub fn u(&mut self) -> f64 {
        (self.next() >> 11) as f64 * (1.0 / 9_007_199_254_740_992.0)
    }
    /// Uniform in [a, b).
    #[inline]
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.u()
    }
    /// Uniform integer in 0..n (0 when n is 0).
    pub fn below(&mut self, n: u32) -> u32 {
        ((self.u() * n as f64) as u32).min(n.saturating_sub(1))
    }
    /// Two independent standard normals by the polar form of Box–Muller (Marsaglia), which
    /// avoids sin/cos. |value| ≤ 12.2 because the uniforms have 53 bits.
    #[inline]
    pub fn normal_pair(&mut self) -> (f64, f64) {
        loop {
            let a = 2.0 * self.u() - 1.0;
            let b = 2.0 * self.u() - 1.0;
            let s = a * a + b * b;
            if s > 0.0 && s < 1.0 {
                let f = (-2.0 * s.ln() / s).sqrt();
                return (a * f, b * f);
            }
        }
    }
}

//! A random forest of classification trees (Breiman 2001) in plain Rust, for the per-point
//! classifier of the labelling stage ([`super::descriptors`]).
//!
//! Training is histogram-based, as in LightGBM and scikit-learn's `HistGradientBoosting`:
//! every feature is cut once into at most [`MAX_BINS`] bins at quantiles of the training
//! values, each point keeps one byte per feature, and a node's best split is found from
//! per-bin class counts instead of sorting. Split quality is the Gini impurity decrease;
//! each node tries `mtry` features drawn at random (√F by default). Each tree grows on its
//! own class-balanced bootstrap sample (equal draws per class, with replacement), which
//! keeps rare classes such as poles from being voted away by the ground and the façades.
//! A leaf stores its class distribution; the forest averages them.
//!
//! Trees are grown in parallel, each from its own seed, so the model does not depend on the
//! number of threads.

use crate::rng::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Most bins per feature (thresholds + 1); bin indices fit a byte.
pub const MAX_BINS: usize = 64;

/// Training parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ForestParams {
    /// Number of trees.
    pub trees: usize,
    /// Deepest level of a tree (the root is level 0).
    pub max_depth: usize,
    /// A node with fewer (bootstrap) points is a leaf.
    pub min_split: usize,
    /// Features tried per node (0: √ of the number of features).
    pub mtry: usize,
    /// Bootstrap draws per class and tree.
    pub per_class: usize,
    /// Seed of the trees' random streams.
    pub seed: u64,
    /// Training points kept per class (a deterministic sample of the labelled points).
    pub max_samples_per_class: usize,
}

impl Default for ForestParams {
    fn default() -> Self {
        ForestParams {
            trees: 24,
            max_depth: 18,
            min_split: 30,
            mtry: 0,
            per_class: 6000,
            seed: 1,
            max_samples_per_class: 60_000,
        }
    }
}

/// One tree, flattened: node `k` is a leaf when `feature[k] == LEAF`, its class
/// distribution at `leaf[k] * classes ..`; otherwise points with `x[feature] <= threshold`
/// go to `left[k]`, the others to `left[k] + 1`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Tree {
    feature: Vec<u16>,
    threshold: Vec<f32>,
    left: Vec<u32>,
    leaf: Vec<f32>,
    /// The same nodes packed for prediction (one cache line holds five of them, where the
    /// three arrays cost three misses per node on a model larger than the cache).
    #[serde(skip)]
    packed: Vec<Node>,
}

#[derive(Debug, Clone, Copy, Default)]
struct Node {
    threshold: f32,
    feature: u16,
    left: u32,
}

const LEAF: u16 = u16::MAX;

impl Tree {
    fn pack(&mut self) {
        self.packed = (0..self.feature.len())
            .map(|k| Node {
                threshold: self.threshold[k],
                feature: self.feature[k],
                left: self.left[k],
            })
            .collect();
    }

    fn leaf_of(&self, x: &[f32]) -> usize {
        let nodes = &self.packed;
        let mut n = nodes[0];
        while n.feature != LEAF {
            let k = n.left as usize + usize::from(x[n.feature as usize] > n.threshold);
            n = nodes[k];
        }
        n.left as usize
    }
    /// Nodes in the tree.
    pub fn nodes(&self) -> usize {
        self.feature.len()
    }
}

/// A trained forest.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Forest {
    /// Number of classes (the caller's class indices 0..classes).
    pub classes: usize,
    /// Number of features per point.
    pub features: usize,
    /// The trees.
    pub trees: Vec<Tree>,
}

impl Forest {
    /// Checks the structure of a forest read from a file, so that prediction cannot index out
    /// of bounds or loop: every split's children come after it, leaves are in range.
    pub fn check(&self) -> std::result::Result<(), String> {
        if self.trees.is_empty() {
            return Err("the forest has no trees".into());
        }
        for (t, tree) in self.trees.iter().enumerate() {
            let n = tree.feature.len();
            let leaves = tree.leaf.len() / self.classes.max(1);
            let bad = n == 0
                || tree.threshold.len() != n
                || tree.left.len() != n
                || tree.leaf.len() % self.classes.max(1) != 0
                || (0..n).any(|k| {
                    let l = tree.left[k] as usize;
                    if tree.feature[k] == LEAF {
                        l >= leaves
                    } else {
                        tree.feature[k] as usize >= self.features || l <= k || l + 1 >= n
                    }
                });
            if bad {
                return Err(format!("tree {t} is malformed"));
            }
        }
        Ok(())
    }

    /// Checks a forest read from a file ([`Forest::check`]) and prepares it for prediction.
    pub fn checked(mut self) -> std::result::Result<Self, String> {
        self.check()?;
        self.trees.iter_mut().for_each(Tree::pack);
        Ok(self)
    }

    /// Mean class distribution of the trees' leaves for one point (`x.len() == features`),
    /// added into `out` (`classes` values; not cleared).
    pub fn vote(&self, x: &[f32], out: &mut [f32]) {
        let c = self.classes;
        let w = 1.0 / self.trees.len().max(1) as f32;
        for t in &self.trees {
            let l = t.leaf_of(x);
            for (o, v) in out.iter_mut().zip(&t.leaf[l * c..(l + 1) * c]) {
                *o += w * v;
            }
        }
    }

    /// The class index with the highest mean vote among those `allowed` (all when empty).
    pub fn predict(&self, x: &[f32], allowed: &[bool], scratch: &mut Vec<f32>) -> usize {
        scratch.clear();
        scratch.resize(self.classes, 0.0);
        self.vote(x, scratch);
        let mut best = (0usize, f32::NEG_INFINITY);
        for (k, &v) in scratch.iter().enumerate() {
            if (allowed.is_empty() || allowed[k]) && v > best.1 {
                best = (k, v);
            }
        }
        best.0
    }

    /// Trains a forest on `x` (row-major, `features` values per point) and class indices
    /// `y` (< `classes`). Non-finite feature values are treated as the lowest bin.
    pub fn train(x: &[f32], y: &[u16], features: usize, classes: usize, p: &ForestParams) -> Self {
        let n = y.len();
        assert_eq!(x.len(), n * features, "feature matrix shape");
        let cuts = cut_points(x, n, features);
        // Bin index per (feature, point): feature-major, so a node's histogram of one feature
        // reads one contiguous row.
        let bins: Vec<Vec<u8>> = (0..features)
            .into_par_iter()
            .map(|f| {
                (0..n)
                    .map(|i| bin_of(&cuts[f], x[i * features + f]))
                    .collect()
            })
            .collect();
        let mut by_class: Vec<Vec<u32>> = vec![Vec::new(); classes];
        for (i, &c) in y.iter().enumerate() {
            by_class[c as usize].push(i as u32);
        }
        let mtry = if p.mtry == 0 {
            ((features as f64).sqrt().round() as usize).max(1)
        } else {
            p.mtry.min(features)
        };
        let trees = (0..p.trees)
            .into_par_iter()
            .map(|t| {
                let mut rng = Rng(p.seed ^ (t as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
                let mut sample = Vec::new();
                for idx in by_class.iter().filter(|v| !v.is_empty()) {
                    for _ in 0..p.per_class {
                        sample.push(idx[rng.below(idx.len() as u32) as usize]);
                    }
                }
                let g = Grower {
                    bins: &bins,
                    cuts: &cuts,
                    y,
                    classes,
                    mtry,
                    p,
                };
                let mut t = g.grow(sample, &mut rng);
                t.pack();
                t
            })
            .collect();
        Forest {
            classes,
            features,
            trees,
        }
    }
}

/// Thresholds per feature: distinct quantiles of (a sample of) the training values.
fn cut_points(x: &[f32], n: usize, features: usize) -> Vec<Vec<f32>> {
    let step = (n / 20_000).max(1);
    (0..features)
        .map(|f| {
            let mut v: Vec<f32> = (0..n)
                .step_by(step)
                .map(|i| x[i * features + f])
                .filter(|v| v.is_finite())
                .collect();
            v.sort_by(f32::total_cmp);
            let mut cuts: Vec<f32> = Vec::new();
            if v.is_empty() {
                return cuts;
            }
            for q in 1..MAX_BINS {
                let t = v[(q * (v.len() - 1)) / MAX_BINS];
                if cuts.last().is_none_or(|&l| t > l) && t < v[v.len() - 1] {
                    cuts.push(t);
                }
            }
            cuts
        })
        .collect()
}

/// Bin of a value: the number of cut points below it (`v <= cuts[b]` for bin `b`).
fn bin_of(cuts: &[f32], v: f32) -> u8 {
    if !v.is_finite() {
        return 0;
    }
    cuts.partition_point(|&c| c < v) as u8
}

struct Grower<'a> {
    bins: &'a [Vec<u8>],
    cuts: &'a [Vec<f32>],
    y: &'a [u16],
    classes: usize,
    mtry: usize,
    p: &'a ForestParams,
}

fn gini(counts: &[f64], total: f64) -> f64 {
    if total <= 0.0 {
        return 0.0;
    }
    1.0 - counts
        .iter()
        .map(|c| (c / total) * (c / total))
        .sum::<f64>()
}

impl Grower<'_> {
    fn grow(&self, sample: Vec<u32>, rng: &mut Rng) -> Tree {
        let c = self.classes;
        let mut tree = Tree::default();
        // (node index, depth, the node's points)
        let mut stack: Vec<(usize, usize, Vec<u32>)> = vec![(0, 0, sample)];
        tree.feature.push(LEAF);
        tree.threshold.push(0.0);
        tree.left.push(0);
        let mut hist = vec![0.0f64; MAX_BINS * c];
        while let Some((node, depth, idx)) = stack.pop() {
            let mut counts = vec![0.0f64; c];
            for &i in &idx {
                counts[self.y[i as usize] as usize] += 1.0;
            }
            let total = idx.len() as f64;
            let pure = counts.iter().filter(|&&v| v > 0.0).count() <= 1;
            let split = if pure || depth >= self.p.max_depth || idx.len() < self.p.min_split {
                None
            } else {
                self.best_split(&idx, &counts, &mut hist, rng)
            };
            let Some((f, b)) = split else {
                tree.left[node] = (tree.leaf.len() / c) as u32;
                tree.leaf.extend(counts.iter().map(|v| (v / total) as f32));
                continue;
            };
            let (l, r): (Vec<u32>, Vec<u32>) =
                idx.iter().partition(|&&i| self.bins[f][i as usize] <= b);
            let k = tree.feature.len();
            for _ in 0..2 {
                tree.feature.push(LEAF);
                tree.threshold.push(0.0);
                tree.left.push(0);
            }
            tree.feature[node] = f as u16;
            tree.threshold[node] = self.cuts[f][b as usize];
            tree.left[node] = k as u32;
            stack.push((k, depth + 1, l));
            stack.push((k + 1, depth + 1, r));
        }
        tree
    }

    /// Best (feature, bin) among `mtry` random features: points with bin ≤ b go left.
    fn best_split(
        &self,
        idx: &[u32],
        counts: &[f64],
        hist: &mut [f64],
        rng: &mut Rng,
    ) -> Option<(usize, u8)> {
        let c = self.classes;
        let nf = self.bins.len();
        let total = idx.len() as f64;
        let parent = gini(counts, total);
        let mut best: Option<(f64, usize, u8)> = None;
        let mut tried = 0;
        let mut order: Vec<usize> = (0..nf).collect();
        // Partial Fisher–Yates: the first `mtry` entries of `order` are the features tried;
        // constant features do not count, as in scikit-learn.
        let mut k = 0;
        while tried < self.mtry && k < nf {
            let j = k + rng.below((nf - k) as u32) as usize;
            order.swap(k, j);
            let f = order[k];
            k += 1;
            let nb = self.cuts[f].len() + 1;
            if nb < 2 {
                continue;
            }
            let h = &mut hist[..nb * c];
            h.fill(0.0);
            let col = &self.bins[f];
            for &i in idx {
                h[col[i as usize] as usize * c + self.y[i as usize] as usize] += 1.0;
            }
            let mut left = vec![0.0f64; c];
            let mut nl = 0.0;
            let mut varied = false;
            for b in 0..nb - 1 {
                let row = &h[b * c..(b + 1) * c];
                for (l, v) in left.iter_mut().zip(row) {
                    *l += v;
                    nl += v;
                }
                if nl == 0.0 || nl == total {
                    continue;
                }
                varied = true;
                let right: Vec<f64> = counts.iter().zip(&left).map(|(a, b)| a - b).collect();
                let nr = total - nl;
                let gain = parent - (nl * gini(&left, nl) + nr * gini(&right, nr)) / total;
                if best.is_none_or(|(g, _, _)| gain > g) {
                    best = Some((gain, f, b as u8));
                }
            }
            if varied {
                tried += 1;
            }
        }
        best.filter(|(g, _, _)| *g > 1e-12).map(|(_, f, b)| (f, b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two features, three classes in separate regions of the plane plus one useless
    /// feature: the forest must classify held-out points almost perfectly.
    #[test]
    fn separates_classes_and_ignores_noise() {
        let mut rng = Rng(5);
        let mut make = |n: usize| {
            let (mut x, mut y) = (Vec::new(), Vec::new());
            for _ in 0..n {
                let (a, b, noise) = (rng.u() as f32, rng.u() as f32, rng.u() as f32);
                let c = if a < 0.3 {
                    0
                } else if b < 0.5 {
                    1
                } else {
                    2
                };
                x.extend([a, b, noise]);
                y.push(c);
            }
            (x, y)
        };
        let (x, y) = make(6000);
        let p = ForestParams {
            trees: 10,
            per_class: 2000,
            ..Default::default()
        };
        let f = Forest::train(&x, &y, 3, 3, &p);
        let (tx, ty) = make(2000);
        let mut s = Vec::new();
        let right = (0..ty.len())
            .filter(|&i| f.predict(&tx[i * 3..i * 3 + 3], &[], &mut s) == ty[i] as usize)
            .count();
        assert!(right as f64 / ty.len() as f64 > 0.97, "{right} of 2000");
        // Restricting the classes: never predicts a forbidden one.
        let allowed = [true, false, true];
        assert!((0..ty.len()).all(|i| f.predict(&tx[i * 3..i * 3 + 3], &allowed, &mut s) != 1));
        // Same seed, same forest, whatever the thread count.
        let g = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| Forest::train(&x, &y, 3, 3, &p));
        assert_eq!(
            serde_json::to_string(&f).unwrap(),
            serde_json::to_string(&g).unwrap()
        );
    }
}

//! Union–find over (tile, local segment) nodes that forgets components once they are final,
//! so it holds only segments of components that can still grow.
//!
//! A node is `slot << 32 | label` (`slot`: the tile's arrival number in this run, internal
//! only). Each root keeps its component's smallest core-point ordinal (the global id to be),
//! the number of its nodes whose tiles are still open, and its member nodes (merged small into
//! large, so a node moves O(log n) times).

use std::collections::HashMap;

/// Node key of local segment `label` of the tile in `slot`.
#[inline]
pub fn node(slot: u32, label: u32) -> u64 {
    ((slot as u64) << 32) | label as u64
}

/// Splits a node key into (slot, label).
#[inline]
pub fn split(node: u64) -> (u32, u32) {
    ((node >> 32) as u32, node as u32)
}

#[derive(Debug)]
struct Comp {
    min_ordinal: u64,
    open: u32,
    members: Vec<u64>,
}

/// A component that became final.
#[derive(Debug, Clone, PartialEq)]
pub struct Final {
    /// Smallest core-point ordinal (`u64::MAX`: no core points, nothing to write).
    pub min_ordinal: u64,
    /// Its nodes.
    pub members: Vec<u64>,
}

/// The union–find.
#[derive(Debug, Default)]
pub struct Components {
    parent: HashMap<u64, u64>,
    comps: HashMap<u64, Comp>,
}

impl Components {
    /// Adds an open singleton node.
    pub fn insert(&mut self, n: u64, min_ordinal: u64) {
        self.parent.insert(n, n);
        self.comps.insert(
            n,
            Comp {
                min_ordinal,
                open: 1,
                members: vec![n],
            },
        );
    }

    /// Nodes held.
    pub fn len(&self) -> usize {
        self.parent.len()
    }

    /// True when no node is held.
    pub fn is_empty(&self) -> bool {
        self.parent.is_empty()
    }

    /// Whether a node is held.
    pub fn contains(&self, n: u64) -> bool {
        self.parent.contains_key(&n)
    }

    /// Root of `n` (with path halving), `None` for an unknown node.
    pub fn find(&mut self, n: u64) -> Option<u64> {
        let mut x = n;
        loop {
            let p = *self.parent.get(&x)?;
            if p == x {
                return Some(x);
            }
            let gp = *self.parent.get(&p)?;
            self.parent.insert(x, gp);
            x = gp;
        }
    }

    /// Joins the components of `a` and `b`; true if they were different.
    pub fn union(&mut self, a: u64, b: u64) -> bool {
        let (Some(ra), Some(rb)) = (self.find(a), self.find(b)) else {
            return false;
        };
        if ra == rb {
            return false;
        }
        let (Some(ca), Some(cb)) = (self.comps.remove(&ra), self.comps.remove(&rb)) else {
            return false;
        };
        let (mut big, small, root, child) = if ca.members.len() >= cb.members.len() {
            (ca, cb, ra, rb)
        } else {
            (cb, ca, rb, ra)
        };
        big.min_ordinal = big.min_ordinal.min(small.min_ordinal);
        big.open += small.open;
        big.members.extend(small.members);
        self.parent.insert(child, root);
        self.comps.insert(root, big);
        true
    }

    /// Marks node `n`'s tile closed. When it was the component's last open node the
    /// component is final: it is removed and returned.
    pub fn close(&mut self, n: u64) -> Option<Final> {
        let r = self.find(n)?;
        let c = self.comps.get_mut(&r)?;
        c.open = c.open.saturating_sub(1);
        if c.open > 0 {
            return None;
        }
        let c = self.comps.remove(&r)?;
        for m in &c.members {
            self.parent.remove(m);
        }
        Some(Final {
            min_ordinal: c.min_ordinal,
            members: c.members,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn final_only_when_every_node_closed_and_then_forgotten() {
        let mut c = Components::default();
        let (a, b, d) = (node(0, 1), node(1, 4), node(2, 2));
        c.insert(a, 50);
        c.insert(b, 7);
        c.insert(d, u64::MAX);
        assert!(c.union(a, b));
        assert!(!c.union(b, a));
        assert!(c.union(d, a));
        assert_eq!(c.find(d), c.find(a));
        assert_eq!(c.close(a), None);
        assert_eq!(c.close(d), None);
        let f = c.close(b).unwrap();
        assert_eq!(f.min_ordinal, 7);
        let mut m = f.members.clone();
        m.sort();
        assert_eq!(m, vec![a, b, d]);
        assert!(c.is_empty());
        assert_eq!(c.find(a), None);
        assert_eq!(split(node(3, 9)), (3, 9));
    }

    #[test]
    fn components_match_a_naive_labelling() {
        // Deterministic pseudo-random unions over 200 nodes vs. a naive relabelling.
        let mut c = Components::default();
        let mut naive: Vec<usize> = (0..200).collect();
        for i in 0..200u32 {
            c.insert(node(i, 1), i as u64);
        }
        let mut s = 12345u64;
        for _ in 0..150 {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let (x, y) = (((s >> 33) % 200) as usize, ((s >> 13) % 200) as usize);
            c.union(node(x as u32, 1), node(y as u32, 1));
            let (lx, ly) = (naive[x], naive[y]);
            for v in naive.iter_mut() {
                if *v == ly {
                    *v = lx;
                }
            }
        }
        for x in 0..200usize {
            for y in 0..200usize {
                let same = c.find(node(x as u32, 1)) == c.find(node(y as u32, 1));
                assert_eq!(same, naive[x] == naive[y]);
            }
        }
        // The minimum of each component is the smallest member index.
        let mut finals = Vec::new();
        for i in 0..200u32 {
            if let Some(f) = c.close(node(i, 1)) {
                finals.push(f);
            }
        }
        assert_eq!(finals.iter().map(|f| f.members.len()).sum::<usize>(), 200);
        for f in finals {
            let min = f.members.iter().map(|&m| split(m).0 as u64).min().unwrap();
            assert_eq!(f.min_ordinal, min);
        }
    }
}

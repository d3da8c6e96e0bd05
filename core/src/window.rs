//! The corrector's sliding window of corrected positions (metres, map plane), oldest first,
//! with its path length kept up to date.

use crate::se2::distance;

/// The window of corrected positions, oldest first, kept contiguous for matching.
/// Dropping from the front moves a start offset; the buffer is compacted when the dead prefix
/// outgrows the live part, so every operation is amortised O(1).
#[derive(Clone, Debug, Default)]
pub(crate) struct Window {
    buf: Vec<[f64; 2]>,
    start: usize,
    /// Path length of the window (metres), kept up to date by `push` and `drop_oldest`; rigid
    /// corrections of the window do not change it.
    path_m: f64,
    /// Beside each position of `buf`, the distance to the next one (metres; 0 for the newest),
    /// as [`Window::spacings`] returns them.
    spacings: Vec<f64>,
    /// False once the positions moved after their spacings were computed.
    spacings_fresh: bool,
}

impl Window {
    /// The positions (metres, map plane), oldest first.
    pub(crate) fn as_slice(&self) -> &[[f64; 2]] {
        &self.buf[self.start..]
    }

    /// The positions, to be moved rigidly; their spacings are computed again when next asked.
    pub(crate) fn as_mut_slice(&mut self) -> &mut [[f64; 2]] {
        self.spacings_fresh = false;
        &mut self.buf[self.start..]
    }

    /// Scales the positions about `center` by `factor` (metres, map plane), and the path with
    /// them.
    pub(crate) fn scale_about(&mut self, center: [f64; 2], factor: f64) {
        for x in self.as_mut_slice() {
            *x = [
                center[0] + factor * (x[0] - center[0]),
                center[1] + factor * (x[1] - center[1]),
            ];
        }
        self.path_m *= factor;
    }

    /// A window of `positions` with path length `path_m` (metres).
    pub(crate) fn restored(positions: Vec<[f64; 2]>, path_m: f64) -> Self {
        Window {
            spacings: vec![0.0; positions.len()],
            spacings_fresh: false,
            buf: positions,
            start: 0,
            path_m,
        }
    }

    /// The distance from each position to the next (metres), 0 for the newest. Computed as the
    /// positions arrive and again only after they moved, so that a step that changed nothing
    /// costs nothing here.
    pub(crate) fn spacings(&mut self) -> &[f64] {
        self.refresh_spacings();
        &self.spacings[self.start..]
    }

    /// Computes the spacings again when the positions moved since they were computed; a push
    /// keeps fresh spacings fresh (it computes the new one the same way).
    pub(crate) fn refresh_spacings(&mut self) {
        if !self.spacings_fresh {
            let w = &self.buf[self.start..];
            let spacings = &mut self.spacings[self.start..];
            for (s, pair) in spacings.iter_mut().zip(w.windows(2)) {
                *s = distance(pair[0], pair[1]);
            }
            if let Some(newest) = spacings.last_mut() {
                *newest = 0.0;
            }
            self.spacings_fresh = true;
        }
    }

    /// The window's path length (metres).
    pub(crate) fn path_m(&self) -> f64 {
        self.path_m
    }

    /// How many positions the window holds.
    pub(crate) fn len(&self) -> usize {
        self.buf.len() - self.start
    }

    /// True when the window holds no position.
    pub(crate) fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Readies the buffers for the next [`Window::push`] ([`crate::headroom::make_room`]).
    pub(crate) fn make_room(&mut self) {
        let next = self.buf.len() + 1;
        crate::headroom::make_room(&mut self.buf, next);
        crate::headroom::make_room(&mut self.spacings, next);
    }

    /// Adds the newest position (metres, map plane).
    pub(crate) fn push(&mut self, p: [f64; 2]) {
        if self.start > 0 && self.start >= self.len() {
            self.buf.drain(..self.start);
            self.spacings.drain(..self.start);
            self.start = 0;
        }
        if let Some(&last) = self.as_slice().last() {
            let spacing = distance(last, p);
            self.path_m += spacing;
            if let Some(newest) = self.spacings.last_mut() {
                *newest = spacing;
            }
        }
        self.buf.push(p);
        self.spacings.push(0.0);
    }

    /// Drops the `count` oldest positions (all of them when fewer).
    pub(crate) fn drop_oldest(&mut self, count: usize) {
        let count = count.min(self.len());
        let w = self.as_slice();
        // The segments that leave with the dropped poses.
        let end = (count + 1).min(w.len());
        self.path_m -= w[..end]
            .windows(2)
            .map(|s| distance(s[0], s[1]))
            .sum::<f64>();
        self.start += count;
        if self.len() < 2 {
            self.path_m = 0.0;
        }
    }

    /// How many of the oldest poses to drop so that the window's path length (metres) is at
    /// most `max_m`, keeping at least `keep` poses. Costs one step per pose dropped.
    pub(crate) fn excess_over_path(&self, max_m: f64, keep: usize) -> usize {
        let w = self.as_slice();
        let mut length = self.path_m;
        let mut drop = 0;
        while length > max_m && w.len() - drop > keep {
            length -= distance(w[drop], w[drop + 1]);
            drop += 1;
        }
        drop
    }

    /// True when the path length of the window (metres) is at least `min_m`. Sums from the
    /// oldest pose and stops once the bound is reached: partial sums of non-negative terms only
    /// grow, so the answer equals comparing the full sum.
    pub(crate) fn path_at_least(&self, min_m: f64) -> bool {
        let mut length = 0.0;
        for w in self.as_slice().windows(2) {
            length += distance(w[1], w[0]);
            if length >= min_m {
                return true;
            }
        }
        length >= min_m
    }
}

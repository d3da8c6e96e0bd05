//! Buffers grown ahead of need, so that a latency path neither reallocates nor page-faults.
//!
//! A buffer that grows by pushing reallocates when it is full and faults in each new page of
//! memory when it first writes there: 1-2 us a fault back to back, 15-20 us on a core that idled
//! between poses (measured on this project's VM, `cargo bench -p lanealign-cli --bench corrector
//! -- --paced 10`). [`make_room`] does both ahead, between poses.

use std::collections::VecDeque;

/// Grows `v` (doubling, as pushes would) until it holds `n` elements without reallocating, and
/// writes its spare memory once; does nothing when it already can. Contents are unchanged.
pub(crate) fn make_room<T: Clone + Default>(v: &mut Vec<T>, n: usize) {
    if v.capacity() < n {
        v.reserve(n - v.len());
        let len = v.len();
        v.resize(v.capacity(), T::default());
        v.truncate(len);
    }
}

/// [`make_room`] for a ring buffer.
pub(crate) fn make_room_in_deque<T: Clone + Default>(v: &mut VecDeque<T>, n: usize) {
    if v.capacity() < n {
        v.reserve(n - v.len());
        let len = v.len();
        v.resize(v.capacity(), T::default());
        v.truncate(len);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn room_made_ahead_is_used_without_reallocating() {
        let mut v: Vec<u32> = (0..5).collect();
        make_room(&mut v, 100);
        assert_eq!(v, [0, 1, 2, 3, 4]);
        assert!(v.capacity() >= 100);
        let buffer = v.as_ptr();
        v.extend(5..100);
        assert_eq!(v.as_ptr(), buffer);
        let capacity = v.capacity();
        make_room(&mut v, 50);
        assert_eq!(v.capacity(), capacity, "room enough: nothing grows");
    }

    #[test]
    fn a_ring_keeps_its_order() {
        let mut v: VecDeque<u32> = (0..8).collect();
        v.rotate_left(3);
        v.pop_front();
        make_room_in_deque(&mut v, 40);
        assert!(v.capacity() >= 40);
        assert_eq!(v.iter().copied().collect::<Vec<_>>(), [4, 5, 6, 7, 0, 1, 2]);
    }
}

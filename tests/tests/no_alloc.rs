//! The corrector's per-pose path allocates nothing in steady state. Buffers grow to the largest
//! size the run has needed and are then reused; once every pose buffer in circulation has been
//! given that size (warm-up: two passes over a real sequence, the window wrapping from the end of
//! the run back to its start), a third pass makes no heap allocation at all.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use lanealign_core::corrector::{Corrector, Status};
use lanealign_core::lane_csv;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::trajectory::{read, Format};
use lanealign_tests::shared_data;

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn steady_state_corrections_do_not_allocate() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let lanes = lane_csv::read(&data.join("reference/lanes/lanes_00.csv")).unwrap();
    let map = Arc::new(LaneMap::new(&lanes).unwrap());
    let odom = read(&data.join("odometry/lidar/00.txt"), Format::Kitti).unwrap();
    let positions: Vec<[f64; 2]> = odom
        .poses
        .iter()
        .map(|p| cam.to_planar(p).planar_position())
        .collect();
    for (preset, method) in [
        (Preset::KissIcp, Method::Paper),
        (Preset::Liodom, Method::Paper),
        (Preset::KissIcp, Method::Robust),
    ] {
        let mut corrector = Corrector::new(map.clone(), method.params(preset));
        for _warm_up in 0..2 {
            for &p in &positions {
                corrector.push(p);
            }
        }
        let before = ALLOCATIONS.load(Ordering::Relaxed);
        let mut accepted = 0;
        for &p in &positions {
            accepted += matches!(corrector.push(p).status, Status::Accepted { .. }) as usize;
        }
        let allocations = ALLOCATIONS.load(Ordering::Relaxed) - before;
        assert!(
            accepted > 1000,
            "{}: the second pass must correct ({accepted} accepted)",
            preset.name()
        );
        assert_eq!(
            allocations,
            0,
            "{}: {allocations} allocations in {} steady-state steps",
            preset.name(),
            positions.len()
        );
    }
}

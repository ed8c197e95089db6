//! Per-pass GPU times: a timestamp query pair around each pass, read back after the
//! submission. The query pool exists only where the device supports timestamps
//! (`DeviceInfo::timestamps_supported`); elsewhere nothing is created or recorded.

use ash::vk;

use crate::vk::{Context, VkError};

/// A timestamp query pool with two queries per pass; destroyed on drop.
pub(super) struct Timestamps<'c> {
    dev: &'c ash::Device,
    pool: vk::QueryPool,
    passes: usize,
}

impl<'c> Timestamps<'c> {
    /// A pool for `passes` passes, or `None` where the device has no timestamps.
    pub(super) fn new(ctx: &'c Context, passes: usize) -> Result<Option<Self>, VkError> {
        if !ctx.info.timestamps_supported {
            return Ok(None);
        }
        let pool = unsafe {
            ctx.device.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(2 * passes as u32),
                None,
            )
        }?;
        Ok(Some(Timestamps {
            dev: &ctx.device,
            pool,
            passes,
        }))
    }

    /// Resets every query (recorded once, before the first pass).
    pub(super) fn reset(&self, cb: vk::CommandBuffer) {
        unsafe {
            self.dev
                .cmd_reset_query_pool(cb, self.pool, 0, 2 * self.passes as u32)
        };
    }

    /// Writes the start (`end` false) or end timestamp of the `k`-th executed pass.
    pub(super) fn write(&self, cb: vk::CommandBuffer, k: usize, end: bool) {
        unsafe {
            self.dev.cmd_write_timestamp(
                cb,
                vk::PipelineStageFlags::ALL_COMMANDS,
                self.pool,
                2 * k as u32 + end as u32,
            )
        };
    }

    /// Waits for the results; per pass (start since the first pass, duration) in ms.
    pub(super) fn read(&self, period_ns: f32) -> Result<Vec<(f64, f64)>, VkError> {
        let mut ts = vec![0u64; 2 * self.passes];
        unsafe {
            self.dev.get_query_pool_results(
                self.pool,
                0,
                &mut ts,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }?;
        Ok(pass_times(&ts, period_ns))
    }
}

impl Drop for Timestamps<'_> {
    fn drop(&mut self) {
        unsafe { self.dev.destroy_query_pool(self.pool, None) };
    }
}

/// Raw (start, end) tick pairs -> per pass (start since the first start, duration) in
/// ms; a tick counter that went backwards gives 0, not a wrapped value.
pub(super) fn pass_times(ticks: &[u64], period_ns: f32) -> Vec<(f64, f64)> {
    let period_ms = period_ns as f64 * 1e-6;
    let t0 = ticks.first().copied().unwrap_or(0);
    ticks
        .chunks_exact(2)
        .map(|p| {
            let start_ms = p[0].saturating_sub(t0) as f64 * period_ms;
            let gpu_ms = p[1].saturating_sub(p[0]) as f64 * period_ms;
            (start_ms, gpu_ms)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn ticks_become_milliseconds_relative_to_the_first_pass() {
        // 2 ns ticks: pass 0 from tick 1000 to 1500, pass 1 from 2000 to 2250.
        let t = super::pass_times(&[1000, 1500, 2000, 2250], 2.0);
        assert_eq!(t.len(), 2);
        assert!((t[0].0 - 0.0).abs() < 1e-12 && (t[0].1 - 1e-3).abs() < 1e-12);
        assert!((t[1].0 - 2e-3).abs() < 1e-12 && (t[1].1 - 5e-4).abs() < 1e-12);
    }

    #[test]
    fn backwards_ticks_give_zero_not_a_wrap() {
        let t = super::pass_times(&[100, 50], 1.0);
        assert_eq!(t, vec![(0.0, 0.0)]);
    }
}

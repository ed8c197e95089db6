//! Barriers: derived (pure) from the declared accesses along the execution order as
//! plain data, then recorded as `vkCmdPipelineBarrier` calls.
//!
//! Rule: a pass touching a buffer whose last recorded access is a write, or writing a
//! buffer last read, waits for that access with one buffer memory barrier (whole
//! buffer); read after read needs none. All of a pass's barriers form one
//! `vkCmdPipelineBarrier` from the union of their source stages to the pass's stage.
//!
//! Bookkeeping of "last access" per buffer (kept exactly as it was, so the recorded
//! commands do not change): a write, or a read of a buffer last read, becomes the last
//! access; a read of a buffer last written becomes `(reader's stage, ReadWrite)`, i.e.
//! the write is carried forward in the reader's stage. So every later access of that
//! buffer, reads included, still gets a barrier (conservative: a second reader waits
//! for the first).

use std::collections::HashMap;

use ash::vk;

use super::{Access, Stage};

impl Stage {
    pub(super) fn flags(self) -> vk::PipelineStageFlags {
        match self {
            Stage::Compute => vk::PipelineStageFlags::COMPUTE_SHADER,
            Stage::Transfer => vk::PipelineStageFlags::TRANSFER,
        }
    }
    pub(super) fn access(self, a: Access) -> vk::AccessFlags {
        match (self, a) {
            (Stage::Compute, Access::Read) => vk::AccessFlags::SHADER_READ,
            (Stage::Compute, Access::Write) => vk::AccessFlags::SHADER_WRITE,
            (Stage::Compute, Access::ReadWrite) => {
                vk::AccessFlags::SHADER_READ | vk::AccessFlags::SHADER_WRITE
            }
            (Stage::Transfer, Access::Read) => vk::AccessFlags::TRANSFER_READ,
            (Stage::Transfer, _) => vk::AccessFlags::TRANSFER_WRITE,
        }
    }
}

/// One buffer memory barrier: buffer `buffer` (graph index), from its last access
/// `src` to the pass's access `dst`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct BufferBarrier {
    pub buffer: usize,
    pub src: (Stage, Access),
    pub dst: (Stage, Access),
}

impl BufferBarrier {
    /// (source, destination) access masks.
    pub(super) fn access_masks(&self) -> (vk::AccessFlags, vk::AccessFlags) {
        (self.src.0.access(self.src.1), self.dst.0.access(self.dst.1))
    }
}

/// The barriers to record before one pass (none: `buffers` is empty).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct PassBarrier {
    pub stage: Stage,
    pub buffers: Vec<BufferBarrier>,
}

impl PassBarrier {
    /// (source, destination) stage masks of the pipeline barrier.
    pub(super) fn stage_masks(&self) -> (vk::PipelineStageFlags, vk::PipelineStageFlags) {
        let src = self
            .buffers
            .iter()
            .fold(vk::PipelineStageFlags::empty(), |s, b| s | b.src.0.flags());
        (src, self.stage.flags())
    }
}

/// The barriers before each pass, given the passes (stage, declared accesses) in
/// execution order.
pub(super) fn derive<'p>(
    passes: impl IntoIterator<Item = (Stage, &'p [(usize, Access)])>,
) -> Vec<PassBarrier> {
    let mut last: HashMap<usize, (Stage, Access)> = HashMap::new();
    let mut out = Vec::new();
    for (stage, accesses) in passes {
        let mut buffers = Vec::new();
        for &(r, a) in accesses {
            if let Some(&(ps, pa)) = last.get(&r)
                && (pa.writes() || a.writes())
            {
                buffers.push(BufferBarrier {
                    buffer: r,
                    src: (ps, pa),
                    dst: (stage, a),
                });
            }
        }
        for &(r, a) in accesses {
            let e = last.entry(r).or_insert((stage, a));
            if a.writes() || !e.1.writes() {
                *e = (stage, a);
            } else {
                *e = (stage, Access::ReadWrite);
            }
        }
        out.push(PassBarrier { stage, buffers });
    }
    out
}

/// Records `barrier` (nothing if it has no buffers); `raw` maps a graph buffer index to
/// its Vulkan handle.
pub(super) fn record(
    dev: &ash::Device,
    cb: vk::CommandBuffer,
    barrier: &PassBarrier,
    raw: impl Fn(usize) -> vk::Buffer,
) {
    if barrier.buffers.is_empty() {
        return;
    }
    let vk_barriers: Vec<vk::BufferMemoryBarrier> = barrier
        .buffers
        .iter()
        .map(|b| {
            let (src, dst) = b.access_masks();
            vk::BufferMemoryBarrier::default()
                .src_access_mask(src)
                .dst_access_mask(dst)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .buffer(raw(b.buffer))
                .offset(0)
                .size(vk::WHOLE_SIZE)
        })
        .collect();
    let (src_stage, dst_stage) = barrier.stage_masks();
    unsafe {
        dev.cmd_pipeline_barrier(
            cb,
            src_stage,
            dst_stage,
            vk::DependencyFlags::empty(),
            &[],
            &vk_barriers,
            &[],
        )
    };
}

/// Makes every write of the command buffer visible to the host for readback.
pub(super) fn record_host_visibility(dev: &ash::Device, cb: vk::CommandBuffer) {
    let host = vk::MemoryBarrier::default()
        .src_access_mask(vk::AccessFlags::SHADER_WRITE | vk::AccessFlags::TRANSFER_WRITE)
        .dst_access_mask(vk::AccessFlags::HOST_READ);
    unsafe {
        dev.cmd_pipeline_barrier(
            cb,
            vk::PipelineStageFlags::COMPUTE_SHADER | vk::PipelineStageFlags::TRANSFER,
            vk::PipelineStageFlags::HOST,
            vk::DependencyFlags::empty(),
            &[host],
            &[],
            &[],
        )
    };
}

#[cfg(test)]
mod tests {
    use super::super::Access::{Read, ReadWrite, Write};
    use super::super::Stage::{Compute, Transfer};
    use super::*;
    use vk::AccessFlags as A;
    use vk::PipelineStageFlags as S;

    /// The single barrier before the second of two passes touching buffer 0.
    fn between(first: (Stage, Access), second: (Stage, Access)) -> PassBarrier {
        let a = [(0, first.1)];
        let b = [(0, second.1)];
        let mut d = derive([(first.0, &a[..]), (second.0, &b[..])]);
        assert!(d[0].buffers.is_empty(), "nothing before the first access");
        d.remove(1)
    }

    fn masks(p: &PassBarrier) -> (S, S, A, A) {
        assert_eq!(p.buffers.len(), 1, "{p:?}");
        let (ss, ds) = p.stage_masks();
        let (sa, da) = p.buffers[0].access_masks();
        (ss, ds, sa, da)
    }

    #[test]
    fn read_after_read_needs_no_barrier() {
        for (s1, s2) in [(Compute, Compute), (Compute, Transfer), (Transfer, Compute)] {
            assert!(between((s1, Read), (s2, Read)).buffers.is_empty());
        }
    }

    #[test]
    fn write_then_read_in_compute() {
        let p = between((Compute, Write), (Compute, Read));
        assert_eq!(
            masks(&p),
            (
                S::COMPUTE_SHADER,
                S::COMPUTE_SHADER,
                A::SHADER_WRITE,
                A::SHADER_READ
            )
        );
    }

    #[test]
    fn read_then_write_in_compute() {
        let p = between((Compute, Read), (Compute, Write));
        assert_eq!(
            masks(&p),
            (
                S::COMPUTE_SHADER,
                S::COMPUTE_SHADER,
                A::SHADER_READ,
                A::SHADER_WRITE
            )
        );
    }

    #[test]
    fn write_then_write_in_transfer() {
        let p = between((Transfer, Write), (Transfer, Write));
        assert_eq!(
            masks(&p),
            (
                S::TRANSFER,
                S::TRANSFER,
                A::TRANSFER_WRITE,
                A::TRANSFER_WRITE
            )
        );
    }

    #[test]
    fn compute_to_transfer_and_back() {
        let p = between((Compute, Write), (Transfer, Read));
        assert_eq!(
            masks(&p),
            (
                S::COMPUTE_SHADER,
                S::TRANSFER,
                A::SHADER_WRITE,
                A::TRANSFER_READ
            )
        );
        let p = between((Transfer, Write), (Compute, ReadWrite));
        assert_eq!(
            masks(&p),
            (
                S::TRANSFER,
                S::COMPUTE_SHADER,
                A::TRANSFER_WRITE,
                A::SHADER_READ | A::SHADER_WRITE
            )
        );
    }

    #[test]
    fn a_read_after_a_write_carries_the_write_forward() {
        // Compute write, transfer read, compute read, compute read: the first read waits
        // for the write; the bookkeeping then holds (Transfer, ReadWrite), so the second
        // read waits for the transfer and the third for the second (in compute).
        let w = [(0, Write)];
        let r = [(0, Read)];
        let d = derive([
            (Compute, &w[..]),
            (Transfer, &r[..]),
            (Compute, &r[..]),
            (Compute, &r[..]),
        ]);
        assert_eq!(d[1].buffers[0].src, (Compute, Write));
        assert_eq!(d[2].buffers[0].src, (Transfer, ReadWrite));
        assert_eq!(
            masks(&d[2]),
            (
                S::TRANSFER,
                S::COMPUTE_SHADER,
                A::TRANSFER_WRITE,
                A::SHADER_READ
            )
        );
        assert_eq!(d[3].buffers[0].src, (Compute, ReadWrite));
        assert_eq!(
            d[3].buffers[0].access_masks().0,
            A::SHADER_READ | A::SHADER_WRITE
        );
    }

    #[test]
    fn one_pipeline_barrier_per_pass_from_the_union_of_source_stages() {
        // Buffer 0 filled (transfer), buffer 1 written by compute, buffer 2 only read:
        // the compute pass reading all three waits on both stages, with two barriers.
        let fill = [(0, Write)];
        let comp = [(1, Write), (2, Read)];
        let last = [(0, Read), (1, Read), (2, Read)];
        let d = derive([
            (Transfer, &fill[..]),
            (Compute, &comp[..]),
            (Compute, &last[..]),
        ]);
        assert!(d[1].buffers.is_empty());
        let p = &d[2];
        assert_eq!(
            p.buffers.iter().map(|b| b.buffer).collect::<Vec<_>>(),
            [0, 1]
        );
        assert_eq!(
            p.stage_masks(),
            (S::TRANSFER | S::COMPUTE_SHADER, S::COMPUTE_SHADER)
        );
    }

    #[test]
    fn accumulation_across_batches_waits_each_time() {
        // fill acc, then three read_write dispatches: each waits for the previous.
        let fill = [(0, Write)];
        let rw = [(0, ReadWrite)];
        let d = derive([
            (Transfer, &fill[..]),
            (Compute, &rw[..]),
            (Compute, &rw[..]),
            (Compute, &rw[..]),
        ]);
        assert_eq!(d[1].buffers[0].src, (Transfer, Write));
        assert_eq!(d[2].buffers[0].src, (Compute, ReadWrite));
        assert_eq!(d[3].buffers[0].src, (Compute, ReadWrite));
        assert!(d.iter().skip(1).all(|p| p.buffers.len() == 1));
    }
}

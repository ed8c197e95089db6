//! A render graph. Each pass declares the resources it reads and writes; `execute`
//! orders the passes by those dependencies (declaration order breaks ties), drops passes
//! whose results nobody uses, inserts the barriers, records one command buffer with a
//! debug label and a timestamp pair per pass, submits it and reports per-pass GPU times.
//!
//! A pass that writes a resource takes its handle by `&mut`, so in Rust code the order
//! of writes is the order of declaration, checked by the borrow checker.
//!
//! `execute` is a composition of four parts, the first two pure (no GPU, unit-tested):
//! - `schedule`: declared accesses -> dependencies -> culling -> execution order;
//! - `barriers`: declared accesses along that order -> barriers as plain data, then
//!   the `vkCmdPipelineBarrier` calls;
//! - `record`: misuse checks, descriptor pool and sets, the commands of each pass;
//! - `timestamps`: a query pool (only where the device supports timestamps) and the
//!   readback into per-pass GPU times.

mod barriers;
mod record;
mod schedule;
mod timestamps;

use std::sync::Arc;

use ash::vk;

use crate::vk::{
    AccelStructure, Buffer, ComputePipeline, Context, MemoryKind, Profiler, Span, VkError,
};

use timestamps::Timestamps;

/// A buffer known to the graph.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct BufferRef(usize);

/// An acceleration structure known to the graph (read-only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AccelRef(usize);

/// How a pass uses a buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Access {
    Read,
    Write,
    ReadWrite,
}

impl Access {
    fn writes(self) -> bool {
        !matches!(self, Access::Read)
    }
}

/// The pipeline stage a pass runs in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Compute,
    Transfer,
}

enum BufSlot<'a> {
    Imported(&'a Buffer),
    Transient(Buffer),
}

impl BufSlot<'_> {
    fn buffer(&self) -> &Buffer {
        match self {
            BufSlot::Imported(b) => b,
            BufSlot::Transient(b) => b,
        }
    }
}

enum PassKind<'a> {
    Dispatch {
        pipeline: &'a ComputePipeline,
        buffers: Vec<(u32, usize)>,
        accels: Vec<(u32, usize)>,
        push: Vec<u8>,
        groups: [u32; 3],
    },
    Copy {
        src: usize,
        dst: usize,
        size: u64,
    },
    Fill {
        dst: usize,
        value: u32,
    },
}

struct Pass<'a> {
    name: String,
    kind: PassKind<'a>,
    accesses: Vec<(usize, Access)>,
}

impl Pass<'_> {
    fn stage(&self) -> Stage {
        match self.kind {
            PassKind::Dispatch { .. } => Stage::Compute,
            _ => Stage::Transfer,
        }
    }
}

/// GPU time of one executed pass.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PassTiming {
    pub name: String,
    pub gpu_ms: f64,
}

/// The graph under construction; `'a` is the lifetime of imported resources.
pub struct Graph<'a> {
    ctx: Arc<Context>,
    buffers: Vec<BufSlot<'a>>,
    accels: Vec<&'a AccelStructure>,
    passes: Vec<Pass<'a>>,
    label: String,
}

/// Builder for one compute dispatch.
pub struct DispatchBuilder<'g, 'a> {
    graph: &'g mut Graph<'a>,
    pass: Pass<'a>,
}

impl<'a> DispatchBuilder<'_, 'a> {
    fn bind(mut self, binding: u32, r: usize, access: Access) -> Self {
        if let PassKind::Dispatch { buffers, .. } = &mut self.pass.kind {
            buffers.push((binding, r));
        }
        self.pass.accesses.push((r, access));
        self
    }
    /// Binds a buffer the pass only reads.
    pub fn read(self, binding: u32, b: &BufferRef) -> Self {
        self.bind(binding, b.0, Access::Read)
    }
    /// Binds a buffer the pass overwrites.
    pub fn write(self, binding: u32, b: &mut BufferRef) -> Self {
        self.bind(binding, b.0, Access::Write)
    }
    /// Binds a buffer the pass reads and updates (accumulation).
    pub fn read_write(self, binding: u32, b: &mut BufferRef) -> Self {
        self.bind(binding, b.0, Access::ReadWrite)
    }
    pub fn accel(mut self, binding: u32, a: AccelRef) -> Self {
        if let PassKind::Dispatch { accels, .. } = &mut self.pass.kind {
            accels.push((binding, a.0));
        }
        self
    }
    /// Push constants (must match the pipeline's block size).
    pub fn push<T: bytemuck::Pod>(mut self, data: &T) -> Self {
        if let PassKind::Dispatch { push, .. } = &mut self.pass.kind {
            *push = bytemuck::bytes_of(data).to_vec();
        }
        self
    }
    /// Adds the pass to the graph.
    pub fn submit(self) {
        self.graph.passes.push(self.pass);
    }
}

impl<'a> Graph<'a> {
    pub fn new(ctx: &Arc<Context>, label: &str) -> Self {
        Graph {
            ctx: ctx.clone(),
            buffers: Vec::new(),
            accels: Vec::new(),
            passes: Vec::new(),
            label: label.into(),
        }
    }

    /// Makes a caller-owned buffer available to passes; its contents after `execute` are
    /// the result (the graph never culls passes that write imported buffers).
    pub fn import(&mut self, b: &'a Buffer) -> BufferRef {
        self.buffers.push(BufSlot::Imported(b));
        BufferRef(self.buffers.len() - 1)
    }

    /// A buffer that lives only while the graph executes.
    pub fn create_buffer(&mut self, name: &str, size: u64) -> Result<BufferRef, VkError> {
        let usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST;
        let b = Buffer::new(&self.ctx, name, size, usage, MemoryKind::Device)?;
        self.buffers.push(BufSlot::Transient(b));
        Ok(BufferRef(self.buffers.len() - 1))
    }

    pub fn import_accel(&mut self, a: &'a AccelStructure) -> AccelRef {
        self.accels.push(a);
        AccelRef(self.accels.len() - 1)
    }

    /// Starts a compute pass dispatching `groups` workgroups.
    pub fn dispatch<'g>(
        &'g mut self,
        name: &str,
        pipeline: &'a ComputePipeline,
        groups: [u32; 3],
    ) -> DispatchBuilder<'g, 'a> {
        let pass = Pass {
            name: name.to_string(),
            kind: PassKind::Dispatch {
                pipeline,
                buffers: Vec::new(),
                accels: Vec::new(),
                push: Vec::new(),
                groups,
            },
            accesses: Vec::new(),
        };
        DispatchBuilder { graph: self, pass }
    }

    /// Copies `src` into `dst` (the smaller of both sizes).
    pub fn copy(&mut self, name: &str, src: &BufferRef, dst: &mut BufferRef) {
        let size = self.buffers[src.0]
            .buffer()
            .size
            .min(self.buffers[dst.0].buffer().size);
        self.passes.push(Pass {
            name: name.into(),
            kind: PassKind::Copy {
                src: src.0,
                dst: dst.0,
                size,
            },
            accesses: vec![(src.0, Access::Read), (dst.0, Access::Write)],
        });
    }

    /// Fills `dst` with a 32-bit value.
    pub fn fill(&mut self, name: &str, dst: &mut BufferRef, value: u32) {
        self.passes.push(Pass {
            name: name.into(),
            kind: PassKind::Fill { dst: dst.0, value },
            accesses: vec![(dst.0, Access::Write)],
        });
    }

    /// Whether buffer `r` is the caller's (its contents are the graph's result).
    fn imported(&self) -> Vec<bool> {
        self.buffers
            .iter()
            .map(|b| matches!(b, BufSlot::Imported(_)))
            .collect()
    }

    /// Records, submits and waits. Per-pass GPU times go to `profiler` (if given) and
    /// are returned (none where the device has no timestamps). Misuse of a dispatch
    /// (a binding left unbound or of the wrong kind, a push-constant block of the wrong
    /// size, too many workgroups) is an error naming the pass, before anything runs.
    pub fn execute(self, profiler: Option<&Profiler>) -> Result<Vec<PassTiming>, VkError> {
        let accesses: Vec<&[(usize, Access)]> =
            self.passes.iter().map(|p| p.accesses.as_slice()).collect();
        let order = schedule::schedule(&accesses, &self.imported());
        if order.is_empty() {
            return Ok(Vec::new());
        }
        record::check(&self, &order)?;
        let barriers = barriers::derive(
            order
                .iter()
                .map(|&i| (self.passes[i].stage(), self.passes[i].accesses.as_slice())),
        );
        let ctx = self.ctx.clone();
        let timestamps = Timestamps::new(&ctx, order.len())?;
        let descriptors = record::Descriptors::new(&self, &order)?;
        let submit_us = profiler.map(|p| p.now_us()).unwrap_or(0.0);
        ctx.submit_and_wait(|cb| {
            let rec = record::Recorder {
                graph: &self,
                cb,
                descriptors: &descriptors,
                timestamps: timestamps.as_ref(),
            };
            rec.record(&order, &barriers);
            Ok(())
        })?;
        let Some(timestamps) = timestamps else {
            return Ok(Vec::new());
        };
        let times = timestamps.read(ctx.info.timestamp_period_ns)?;
        let mut timings = Vec::with_capacity(order.len());
        for (&i, (start_ms, gpu_ms)) in order.iter().zip(times) {
            let name = self.passes[i].name.clone();
            if let Some(p) = profiler {
                p.push(Span {
                    name: name.clone(),
                    track: "gpu",
                    start_us: submit_us + start_ms * 1e3,
                    dur_us: gpu_ms * 1e3,
                    thread: String::new(),
                });
            }
            timings.push(PassTiming { name, gpu_ms });
        }
        Ok(timings)
    }
}

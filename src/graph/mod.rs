//! A render graph. Each pass declares the resources it reads and writes; `execute`
//! orders the passes by those dependencies (declaration order breaks ties), drops passes
//! whose results nobody uses, inserts the barriers, records one command buffer with a
//! debug label and a timestamp pair per pass, submits it and reports per-pass GPU times.
//!
//! A pass that writes a resource takes its handle by `&mut`, so in Rust code the order
//! of writes is the order of declaration, checked by the borrow checker.

use std::collections::HashMap;
use std::sync::Arc;

use ash::vk;

use crate::vk::{
    AccelStructure, BindingKind, Buffer, ComputePipeline, Context, MemoryKind, Profiler, Span,
    VkError,
};

/// A buffer known to the graph.
#[derive(Debug, PartialEq, Eq, Hash)]
pub struct BufferRef(usize);

/// An acceleration structure known to the graph (read-only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AccelRef(usize);

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

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Stage {
    Compute,
    Transfer,
}

impl Stage {
    fn flags(self) -> vk::PipelineStageFlags {
        match self {
            Stage::Compute => vk::PipelineStageFlags::COMPUTE_SHADER,
            Stage::Transfer => vk::PipelineStageFlags::TRANSFER,
        }
    }
    fn access(self, a: Access) -> vk::AccessFlags {
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

    /// Execution order: a topological order of the dependency graph (read-after-write,
    /// write-after-read, write-after-write), declaration order breaking ties, without
    /// passes that contribute to no imported buffer.
    fn schedule(&self) -> Vec<usize> {
        let n = self.passes.len();
        let mut deps: Vec<Vec<usize>> = vec![Vec::new(); n];
        let mut last_writer: HashMap<usize, usize> = HashMap::new();
        let mut readers: HashMap<usize, Vec<usize>> = HashMap::new();
        for (i, p) in self.passes.iter().enumerate() {
            for &(r, a) in &p.accesses {
                if let Some(&w) = last_writer.get(&r) {
                    deps[i].push(w);
                }
                if a.writes() {
                    deps[i].extend(
                        readers
                            .remove(&r)
                            .unwrap_or_default()
                            .into_iter()
                            .filter(|&x| x != i),
                    );
                }
            }
            for &(r, a) in &p.accesses {
                if a.writes() {
                    last_writer.insert(r, i);
                } else {
                    readers.entry(r).or_default().push(i);
                }
            }
        }
        // Culling: keep passes that write an imported buffer and everything they need.
        let mut keep = vec![false; n];
        let mut stack: Vec<usize> = (0..n)
            .filter(|&i| {
                self.passes[i]
                    .accesses
                    .iter()
                    .any(|&(r, a)| a.writes() && matches!(self.buffers[r], BufSlot::Imported(_)))
            })
            .collect();
        while let Some(i) = stack.pop() {
            if !keep[i] {
                keep[i] = true;
                stack.extend(deps[i].iter().copied());
            }
        }
        // Kahn's algorithm, always taking the earliest-declared ready pass.
        let mut indeg: Vec<usize> = (0..n)
            .map(|i| deps[i].iter().filter(|&&d| keep[d]).count())
            .collect();
        let mut order = Vec::new();
        let mut done = vec![false; n];
        while let Some(i) = (0..n).find(|&i| keep[i] && !done[i] && indeg[i] == 0) {
            done[i] = true;
            order.push(i);
            for j in 0..n {
                if keep[j] && !done[j] {
                    indeg[j] -= deps[j].iter().filter(|&&d| d == i).count();
                }
            }
        }
        order
    }

    /// Records, submits and waits. Per-pass GPU times go to `profiler` (if given) and
    /// are returned.
    pub fn execute(self, profiler: Option<&Profiler>) -> Result<Vec<PassTiming>, VkError> {
        let ctx = self.ctx.clone();
        let dev = &ctx.device;
        let order = self.schedule();
        if order.is_empty() {
            return Ok(Vec::new());
        }
        let timestamps = ctx.info.timestamps_supported;
        let nq = 2 * order.len() as u32;
        let query_pool = unsafe {
            dev.create_query_pool(
                &vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(nq),
                None,
            )
        }?;
        let mut pool_sizes: HashMap<vk::DescriptorType, u32> = HashMap::new();
        let mut sets_needed = 0;
        for &i in &order {
            if let PassKind::Dispatch { pipeline, .. } = &self.passes[i].kind {
                sets_needed += 1;
                for b in &pipeline.bindings {
                    *pool_sizes.entry(b.descriptor_type()).or_default() += 1;
                }
            }
        }
        let sizes: Vec<vk::DescriptorPoolSize> = pool_sizes
            .iter()
            .map(|(&ty, &n)| vk::DescriptorPoolSize {
                ty,
                descriptor_count: n,
            })
            .collect();
        let desc_pool = if sets_needed > 0 {
            match unsafe {
                dev.create_descriptor_pool(
                    &vk::DescriptorPoolCreateInfo::default()
                        .max_sets(sets_needed)
                        .pool_sizes(&sizes),
                    None,
                )
            } {
                Ok(p) => p,
                Err(e) => {
                    unsafe { dev.destroy_query_pool(query_pool, None) };
                    return Err(e.into());
                }
            }
        } else {
            vk::DescriptorPool::null()
        };
        let result = self.record_and_run(&order, query_pool, desc_pool, timestamps, profiler);
        unsafe {
            if desc_pool != vk::DescriptorPool::null() {
                dev.destroy_descriptor_pool(desc_pool, None);
            }
            dev.destroy_query_pool(query_pool, None);
        }
        result
    }

    fn record_and_run(
        &self,
        order: &[usize],
        query_pool: vk::QueryPool,
        desc_pool: vk::DescriptorPool,
        timestamps: bool,
        profiler: Option<&Profiler>,
    ) -> Result<Vec<PassTiming>, VkError> {
        let ctx = &self.ctx;
        let dev = &ctx.device;
        // Descriptor sets first (they must be written before recording uses them).
        let mut sets: HashMap<usize, vk::DescriptorSet> = HashMap::new();
        for &i in order {
            let PassKind::Dispatch {
                pipeline,
                buffers,
                accels,
                ..
            } = &self.passes[i].kind
            else {
                continue;
            };
            let layouts = [pipeline.set_layout];
            let set = unsafe {
                dev.allocate_descriptor_sets(
                    &vk::DescriptorSetAllocateInfo::default()
                        .descriptor_pool(desc_pool)
                        .set_layouts(&layouts),
                )
            }?[0];
            for (binding, kind) in pipeline.bindings.iter().enumerate() {
                let binding = binding as u32;
                let bound = match kind {
                    BindingKind::StorageBuffer => buffers.iter().any(|&(b, _)| b == binding),
                    BindingKind::AccelerationStructure => accels.iter().any(|&(b, _)| b == binding),
                };
                if !bound {
                    return Err(VkError::Other(format!(
                        "pass {:?}: binding {binding} of pipeline {:?} is not bound",
                        self.passes[i].name, pipeline.name
                    )));
                }
            }
            for &(binding, r) in buffers {
                let info = [vk::DescriptorBufferInfo::default()
                    .buffer(self.buffers[r].buffer().raw)
                    .offset(0)
                    .range(vk::WHOLE_SIZE)];
                let w = vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(binding)
                    .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                    .buffer_info(&info);
                unsafe { dev.update_descriptor_sets(&[w], &[]) };
            }
            for &(binding, a) in accels {
                let handles = [self.accels[a].raw];
                let mut as_info = vk::WriteDescriptorSetAccelerationStructureKHR::default()
                    .acceleration_structures(&handles);
                let w = vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(binding)
                    .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
                    .descriptor_count(1)
                    .push_next(&mut as_info);
                unsafe { dev.update_descriptor_sets(&[w], &[]) };
            }
            sets.insert(i, set);
        }

        let submit_us = profiler.map(|p| p.now_us()).unwrap_or(0.0);
        ctx.submit_and_wait(|cb| {
            ctx.begin_label(cb, &self.label);
            if timestamps {
                unsafe { dev.cmd_reset_query_pool(cb, query_pool, 0, 2 * order.len() as u32) };
            }
            // Last access of each buffer so far: (stage, access).
            let mut last: HashMap<usize, (Stage, Access)> = HashMap::new();
            for (k, &i) in order.iter().enumerate() {
                let pass = &self.passes[i];
                let stage = pass.stage();
                let mut src_stage = vk::PipelineStageFlags::empty();
                let mut barriers = Vec::new();
                for &(r, a) in &pass.accesses {
                    if let Some(&(ps, pa)) = last.get(&r) {
                        // Read after read needs no barrier; everything else does.
                        if pa.writes() || a.writes() {
                            src_stage |= ps.flags();
                            barriers.push(
                                vk::BufferMemoryBarrier::default()
                                    .src_access_mask(ps.access(pa))
                                    .dst_access_mask(stage.access(a))
                                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                                    .buffer(self.buffers[r].buffer().raw)
                                    .offset(0)
                                    .size(vk::WHOLE_SIZE),
                            );
                        }
                    }
                }
                if !barriers.is_empty() {
                    unsafe {
                        dev.cmd_pipeline_barrier(
                            cb,
                            src_stage,
                            stage.flags(),
                            vk::DependencyFlags::empty(),
                            &[],
                            &barriers,
                            &[],
                        )
                    };
                }
                for &(r, a) in &pass.accesses {
                    // A read after a write keeps the write as "last" for the next barrier.
                    let e = last.entry(r).or_insert((stage, a));
                    if a.writes() || !e.1.writes() {
                        *e = (stage, a);
                    } else {
                        *e = (stage, Access::ReadWrite);
                    }
                }
                ctx.begin_label(cb, &pass.name);
                if timestamps {
                    unsafe {
                        dev.cmd_write_timestamp(
                            cb,
                            vk::PipelineStageFlags::ALL_COMMANDS,
                            query_pool,
                            2 * k as u32,
                        )
                    };
                }
                match &pass.kind {
                    PassKind::Dispatch {
                        pipeline,
                        push,
                        groups,
                        ..
                    } => unsafe {
                        dev.cmd_bind_pipeline(
                            cb,
                            vk::PipelineBindPoint::COMPUTE,
                            pipeline.pipeline,
                        );
                        dev.cmd_bind_descriptor_sets(
                            cb,
                            vk::PipelineBindPoint::COMPUTE,
                            pipeline.layout,
                            0,
                            &[sets[&i]],
                            &[],
                        );
                        if !push.is_empty() {
                            dev.cmd_push_constants(
                                cb,
                                pipeline.layout,
                                vk::ShaderStageFlags::COMPUTE,
                                0,
                                push,
                            );
                        }
                        dev.cmd_dispatch(cb, groups[0], groups[1], groups[2]);
                    },
                    PassKind::Copy { src, dst, size } => unsafe {
                        let region = [vk::BufferCopy::default().size(*size)];
                        dev.cmd_copy_buffer(
                            cb,
                            self.buffers[*src].buffer().raw,
                            self.buffers[*dst].buffer().raw,
                            &region,
                        );
                    },
                    PassKind::Fill { dst, value } => unsafe {
                        dev.cmd_fill_buffer(
                            cb,
                            self.buffers[*dst].buffer().raw,
                            0,
                            vk::WHOLE_SIZE,
                            *value,
                        );
                    },
                }
                if timestamps {
                    unsafe {
                        dev.cmd_write_timestamp(
                            cb,
                            vk::PipelineStageFlags::ALL_COMMANDS,
                            query_pool,
                            2 * k as u32 + 1,
                        )
                    };
                }
                ctx.end_label(cb);
            }
            // Make every write visible to the host for readback.
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
            ctx.end_label(cb);
            Ok(())
        })?;

        let mut timings = Vec::new();
        if timestamps {
            let mut ts = vec![0u64; 2 * order.len()];
            unsafe {
                dev.get_query_pool_results(
                    query_pool,
                    0,
                    &mut ts,
                    vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
                )
            }?;
            let period_ms = ctx.info.timestamp_period_ns as f64 * 1e-6;
            let t0 = ts[0];
            for (k, &i) in order.iter().enumerate() {
                let start_ms = ts[2 * k].saturating_sub(t0) as f64 * period_ms;
                let gpu_ms = ts[2 * k + 1].saturating_sub(ts[2 * k]) as f64 * period_ms;
                let name = self.passes[i].name.clone();
                if let Some(p) = profiler {
                    p.push(Span {
                        name: name.clone(),
                        track: "gpu",
                        start_us: submit_us + start_ms * 1e3,
                        dur_us: gpu_ms * 1e3,
                    });
                }
                timings.push(PassTiming { name, gpu_ms });
            }
        }
        Ok(timings)
    }
}

//! Recording: misuse checks, descriptor sets, and the commands of each pass in order
//! (barriers, debug label, timestamps, the pass's own command).

use std::collections::HashMap;

use ash::vk;

use super::barriers::{self, PassBarrier};
use super::timestamps::Timestamps;
use super::{Graph, PassKind};
use crate::vk::{BindingKind, VkError};

/// What a pipeline declares, as plain data.
pub(super) struct Layout<'p> {
    pub name: &'p str,
    pub bindings: &'p [BindingKind],
    pub push_size: u32,
}

/// What a dispatch pass binds, as plain data.
pub(super) struct Bound<'p> {
    pub buffers: &'p [(u32, usize)],
    pub accels: &'p [(u32, usize)],
    pub push_len: usize,
    pub groups: [u32; 3],
}

/// Checks one dispatch against its pipeline and the device's workgroup limit.
pub(super) fn check_dispatch(
    pass: &str,
    layout: &Layout,
    bound: &Bound,
    max_groups: [u32; 3],
) -> Result<(), VkError> {
    // A buffer goes to a storage or texel buffer binding (the pipeline says which).
    let given = bound
        .buffers
        .iter()
        .map(|&(b, _)| {
            let declared = layout.bindings.get(b as usize).copied();
            let kind = match declared {
                Some(k) if k.takes_buffer() => k,
                _ => BindingKind::StorageBuffer,
            };
            (b, kind)
        })
        .chain(
            bound
                .accels
                .iter()
                .map(|&(b, _)| (b, BindingKind::AccelerationStructure)),
        );
    for (binding, kind) in given {
        let declared = layout.bindings.get(binding as usize).copied();
        if declared != Some(kind) {
            return Err(VkError::BindingMismatch {
                pass: pass.into(),
                pipeline: layout.name.into(),
                binding,
                bound: kind,
                declared,
                count: layout.bindings.len(),
            });
        }
    }
    for (binding, &kind) in layout.bindings.iter().enumerate() {
        let binding = binding as u32;
        let list = match kind {
            BindingKind::StorageBuffer | BindingKind::TexelBuffer => bound.buffers,
            BindingKind::AccelerationStructure => bound.accels,
        };
        if !list.iter().any(|&(b, _)| b == binding) {
            return Err(VkError::UnboundBinding {
                pass: pass.into(),
                pipeline: layout.name.into(),
                binding,
                kind,
            });
        }
    }
    if bound.push_len != layout.push_size as usize {
        return Err(VkError::PushConstantSize {
            pass: pass.into(),
            pipeline: layout.name.into(),
            expected: layout.push_size,
            given: bound.push_len,
        });
    }
    if (0..3).any(|d| bound.groups[d] > max_groups[d]) {
        return Err(VkError::WorkgroupLimit {
            pass: pass.into(),
            groups: bound.groups,
            max: max_groups,
        });
    }
    Ok(())
}

/// Checks every dispatch that will run.
pub(super) fn check(g: &Graph, order: &[usize]) -> Result<(), VkError> {
    for &i in order {
        let pass = &g.passes[i];
        if let PassKind::Dispatch {
            pipeline,
            buffers,
            accels,
            push,
            groups,
        } = &pass.kind
        {
            let layout = Layout {
                name: &pipeline.name,
                bindings: &pipeline.bindings,
                push_size: pipeline.push_constant_size,
            };
            let bound = Bound {
                buffers,
                accels,
                push_len: push.len(),
                groups: *groups,
            };
            check_dispatch(&pass.name, &layout, &bound, g.ctx.info.max_workgroup_count)?;
        }
    }
    Ok(())
}

/// The descriptor pool and one written set per executed dispatch; the pool is
/// destroyed on drop.
pub(super) struct Descriptors<'c> {
    dev: &'c ash::Device,
    pool: vk::DescriptorPool,
    sets: HashMap<usize, vk::DescriptorSet>,
    /// The texel buffers' views, one per graph buffer however many dispatches read it
    /// (destroyed with the pool).
    views: HashMap<usize, vk::BufferView>,
}

impl<'c> Descriptors<'c> {
    pub(super) fn new(g: &'c Graph, order: &[usize]) -> Result<Self, VkError> {
        let dev = &g.ctx.device;
        let mut pool_sizes: HashMap<vk::DescriptorType, u32> = HashMap::new();
        let mut sets_needed = 0;
        for &i in order {
            if let PassKind::Dispatch { pipeline, .. } = &g.passes[i].kind {
                sets_needed += 1;
                for b in &pipeline.bindings {
                    *pool_sizes.entry(b.descriptor_type()).or_default() += 1;
                }
            }
        }
        let mut d = Descriptors {
            dev,
            pool: vk::DescriptorPool::null(),
            sets: HashMap::new(),
            views: HashMap::new(),
        };
        if sets_needed == 0 {
            return Ok(d);
        }
        let sizes: Vec<vk::DescriptorPoolSize> = pool_sizes
            .iter()
            .map(|(&ty, &n)| vk::DescriptorPoolSize {
                ty,
                descriptor_count: n,
            })
            .collect();
        d.pool = unsafe {
            dev.create_descriptor_pool(
                &vk::DescriptorPoolCreateInfo::default()
                    .max_sets(sets_needed)
                    .pool_sizes(&sizes),
                None,
            )
        }?;
        for &i in order {
            if let Some(set) = d.write_set(g, i)? {
                d.sets.insert(i, set);
            }
        }
        Ok(d)
    }

    /// Allocates and writes the set of pass `i` (none for copies and fills).
    fn write_set(&mut self, g: &Graph, i: usize) -> Result<Option<vk::DescriptorSet>, VkError> {
        let PassKind::Dispatch {
            pipeline,
            buffers,
            accels,
            ..
        } = &g.passes[i].kind
        else {
            return Ok(None);
        };
        let layouts = [pipeline.set_layout];
        let set = unsafe {
            self.dev.allocate_descriptor_sets(
                &vk::DescriptorSetAllocateInfo::default()
                    .descriptor_pool(self.pool)
                    .set_layouts(&layouts),
            )
        }?[0];
        for &(binding, r) in buffers {
            let buffer = g.buffers[r].buffer();
            if pipeline.bindings.get(binding as usize) == Some(&BindingKind::TexelBuffer) {
                let view = match self.views.get(&r) {
                    Some(&v) => v,
                    None => {
                        // The whole buffer in 16-byte texels (a trailing part of a texel
                        // is not addressable).
                        let range = buffer.size / 16 * 16;
                        let v = unsafe {
                            self.dev.create_buffer_view(
                                &vk::BufferViewCreateInfo::default()
                                    .buffer(buffer.raw)
                                    .format(crate::vk::TEXEL_BUFFER_FORMAT)
                                    .offset(0)
                                    .range(range),
                                None,
                            )
                        }?;
                        self.views.insert(r, v);
                        v
                    }
                };
                let views = [view];
                let w = vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(binding)
                    .descriptor_type(vk::DescriptorType::UNIFORM_TEXEL_BUFFER)
                    .texel_buffer_view(&views);
                unsafe { self.dev.update_descriptor_sets(&[w], &[]) };
                continue;
            }
            let info = [vk::DescriptorBufferInfo::default()
                .buffer(buffer.raw)
                .offset(0)
                .range(vk::WHOLE_SIZE)];
            let w = vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(binding)
                .descriptor_type(vk::DescriptorType::STORAGE_BUFFER)
                .buffer_info(&info);
            unsafe { self.dev.update_descriptor_sets(&[w], &[]) };
        }
        for &(binding, a) in accels {
            let handles = [g.accels[a].raw];
            let mut as_info = vk::WriteDescriptorSetAccelerationStructureKHR::default()
                .acceleration_structures(&handles);
            let w = vk::WriteDescriptorSet::default()
                .dst_set(set)
                .dst_binding(binding)
                .descriptor_type(vk::DescriptorType::ACCELERATION_STRUCTURE_KHR)
                .descriptor_count(1)
                .push_next(&mut as_info);
            unsafe { self.dev.update_descriptor_sets(&[w], &[]) };
        }
        Ok(Some(set))
    }
}

impl Drop for Descriptors<'_> {
    fn drop(&mut self) {
        for &v in self.views.values() {
            unsafe { self.dev.destroy_buffer_view(v, None) };
        }
        if self.pool != vk::DescriptorPool::null() {
            unsafe { self.dev.destroy_descriptor_pool(self.pool, None) };
        }
    }
}

/// Records a scheduled graph into one command buffer.
pub(super) struct Recorder<'r, 'a> {
    pub graph: &'r Graph<'a>,
    pub cb: vk::CommandBuffer,
    pub descriptors: &'r Descriptors<'r>,
    pub timestamps: Option<&'r Timestamps<'r>>,
}

impl Recorder<'_, '_> {
    /// The whole command buffer: the passes of `order`, each after its barriers
    /// (`barriers[k]` before `order[k]`), inside the graph's debug label.
    pub(super) fn record(&self, order: &[usize], barriers: &[PassBarrier]) {
        let (g, cb) = (self.graph, self.cb);
        let dev = &g.ctx.device;
        g.ctx.begin_label(cb, &g.label);
        if let Some(ts) = self.timestamps {
            ts.reset(cb);
        }
        for (k, (&i, barrier)) in order.iter().zip(barriers).enumerate() {
            barriers::record(dev, cb, barrier, |r| g.buffers[r].buffer().raw);
            g.ctx.begin_label(cb, &g.passes[i].name);
            if let Some(ts) = self.timestamps {
                ts.write(cb, k, false);
            }
            self.pass_commands(i);
            if let Some(ts) = self.timestamps {
                ts.write(cb, k, true);
            }
            g.ctx.end_label(cb);
        }
        barriers::record_host_visibility(dev, cb);
        g.ctx.end_label(cb);
    }

    /// The command(s) of pass `i` itself.
    fn pass_commands(&self, i: usize) {
        let (g, cb) = (self.graph, self.cb);
        let dev = &g.ctx.device;
        match &g.passes[i].kind {
            PassKind::Dispatch {
                pipeline,
                push,
                groups,
                ..
            } => unsafe {
                dev.cmd_bind_pipeline(cb, vk::PipelineBindPoint::COMPUTE, pipeline.pipeline);
                dev.cmd_bind_descriptor_sets(
                    cb,
                    vk::PipelineBindPoint::COMPUTE,
                    pipeline.layout,
                    0,
                    &[self.descriptors.sets[&i]],
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
                g.ctx.note_dispatch(&pipeline.name);
            },
            PassKind::Copy { src, dst, size } => unsafe {
                let region = [vk::BufferCopy::default().size(*size)];
                dev.cmd_copy_buffer(
                    cb,
                    g.buffers[*src].buffer().raw,
                    g.buffers[*dst].buffer().raw,
                    &region,
                );
            },
            PassKind::Fill { dst, value } => unsafe {
                dev.cmd_fill_buffer(cb, g.buffers[*dst].buffer().raw, 0, vk::WHOLE_SIZE, *value);
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use BindingKind::{AccelerationStructure as Accel, StorageBuffer as Storage};

    const LIMIT: [u32; 3] = [65_535, 65_535, 65_535];

    fn layout(bindings: &[BindingKind]) -> Layout<'_> {
        Layout {
            name: "pipe",
            bindings,
            push_size: 16,
        }
    }

    fn bound<'p>(buffers: &'p [(u32, usize)], accels: &'p [(u32, usize)]) -> Bound<'p> {
        Bound {
            buffers,
            accels,
            push_len: 16,
            groups: [4, 1, 1],
        }
    }

    #[test]
    fn a_fully_bound_dispatch_passes() {
        let l = layout(&[Accel, Storage, Storage]);
        check_dispatch("p", &l, &bound(&[(1, 0), (2, 1)], &[(0, 0)]), LIMIT).unwrap();
    }

    /// A buffer goes to a storage or a texel buffer binding, as the pipeline declares;
    /// an acceleration structure at a texel buffer binding, or a texel buffer binding
    /// left unbound, is an error.
    #[test]
    fn a_buffer_binds_to_a_texel_buffer_binding() {
        use BindingKind::TexelBuffer as Texels;
        let l = layout(&[Texels, Storage]);
        check_dispatch("p", &l, &bound(&[(0, 0), (1, 1)], &[]), LIMIT).unwrap();
        let e = check_dispatch("p", &l, &bound(&[(1, 1)], &[(0, 0)]), LIMIT).unwrap_err();
        assert!(
            matches!(
                e,
                VkError::BindingMismatch {
                    binding: 0,
                    bound: Accel,
                    declared: Some(Texels),
                    ..
                }
            ),
            "{e:?}"
        );
        let e = check_dispatch("p", &l, &bound(&[(1, 1)], &[]), LIMIT).unwrap_err();
        assert!(
            matches!(
                e,
                VkError::UnboundBinding {
                    binding: 0,
                    kind: Texels,
                    ..
                }
            ),
            "{e:?}"
        );
    }

    #[test]
    fn an_unbound_binding_names_pass_pipeline_and_binding() {
        let l = layout(&[Storage, Storage]);
        let e = check_dispatch("shade", &l, &bound(&[(0, 0)], &[]), LIMIT).unwrap_err();
        match &e {
            VkError::UnboundBinding {
                pass,
                pipeline,
                binding: 1,
                kind: Storage,
            } => assert_eq!((pass.as_str(), pipeline.as_str()), ("shade", "pipe")),
            other => panic!("{other:?}"),
        }
        let msg = e.to_string();
        assert!(
            msg.contains("\"shade\"") && msg.contains("binding 1"),
            "{msg}"
        );
    }

    #[test]
    fn a_binding_of_the_wrong_kind_or_past_the_layout_is_a_mismatch() {
        let l = layout(&[Accel, Storage]);
        let e = check_dispatch("p", &l, &bound(&[(0, 0), (1, 1)], &[]), LIMIT).unwrap_err();
        assert!(
            matches!(
                e,
                VkError::BindingMismatch {
                    binding: 0,
                    bound: Storage,
                    declared: Some(Accel),
                    ..
                }
            ),
            "{e:?}"
        );
        let e = check_dispatch("p", &l, &bound(&[(1, 0), (5, 1)], &[(0, 0)]), LIMIT).unwrap_err();
        assert!(
            matches!(
                e,
                VkError::BindingMismatch {
                    binding: 5,
                    declared: None,
                    count: 2,
                    ..
                }
            ),
            "{e:?}"
        );
    }

    #[test]
    fn a_push_block_of_another_size_is_refused() {
        let l = layout(&[Storage]);
        for push_len in [0, 12, 20] {
            let b = Bound {
                push_len,
                ..bound(&[(0, 0)], &[])
            };
            let e = check_dispatch("p", &l, &b, LIMIT).unwrap_err();
            assert!(
                matches!(e, VkError::PushConstantSize { expected: 16, given, .. } if given == push_len),
                "{e:?}"
            );
        }
    }

    #[test]
    fn too_many_workgroups_in_any_dimension_are_refused() {
        let l = layout(&[Storage]);
        for groups in [[65_536, 1, 1], [1, 70_000, 1], [1, 1, 65_536]] {
            let b = Bound {
                groups,
                ..bound(&[(0, 0)], &[])
            };
            let e = check_dispatch("big", &l, &b, LIMIT).unwrap_err();
            assert!(
                matches!(&e, VkError::WorkgroupLimit { pass, max, .. } if pass == "big" && *max == LIMIT),
                "{e:?}"
            );
        }
        let b = Bound {
            groups: LIMIT,
            ..bound(&[(0, 0)], &[])
        };
        check_dispatch("edge", &l, &b, LIMIT).unwrap();
    }
}

//! Compute pipelines from build.rs SPIR-V and their descriptor set layouts.

use std::sync::Arc;

use ash::vk;

use super::{Context, VkError};

/// The kind of one descriptor binding (set 0, binding = index in the list).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BindingKind {
    StorageBuffer,
    AccelerationStructure,
    /// A buffer read as a uniform texel buffer of 16-byte texels
    /// ([`TEXEL_BUFFER_FORMAT`]; GLSL `usamplerBuffer`, `texelFetch`).
    TexelBuffer,
}

/// The format of every [`BindingKind::TexelBuffer`]'s view: four 32-bit words a texel.
pub const TEXEL_BUFFER_FORMAT: vk::Format = vk::Format::R32G32B32A32_UINT;

impl BindingKind {
    pub fn descriptor_type(self) -> vk::DescriptorType {
        match self {
            BindingKind::StorageBuffer => vk::DescriptorType::STORAGE_BUFFER,
            BindingKind::AccelerationStructure => vk::DescriptorType::ACCELERATION_STRUCTURE_KHR,
            BindingKind::TexelBuffer => vk::DescriptorType::UNIFORM_TEXEL_BUFFER,
        }
    }

    /// Whether a buffer is bound at a binding of this kind (not an acceleration
    /// structure).
    pub fn takes_buffer(self) -> bool {
        matches!(self, BindingKind::StorageBuffer | BindingKind::TexelBuffer)
    }
}

/// A compute pipeline with one descriptor set and a push-constant block.
pub struct ComputePipeline {
    ctx: Arc<Context>,
    pub name: String,
    pub pipeline: vk::Pipeline,
    pub layout: vk::PipelineLayout,
    pub set_layout: vk::DescriptorSetLayout,
    pub bindings: Vec<BindingKind>,
    pub push_constant_size: u32,
    pub local_size: [u32; 3],
}

impl ComputePipeline {
    /// `specialization`: (constant_id, value) of the shader's 32-bit specialization
    /// constants to set; those not given keep their defaults.
    pub fn new(
        ctx: &Arc<Context>,
        name: &str,
        spirv: &[u32],
        bindings: &[BindingKind],
        push_constant_size: u32,
        local_size: [u32; 3],
        specialization: &[(u32, u32)],
    ) -> Result<ComputePipeline, VkError> {
        let dev = &ctx.device;
        let layout_bindings: Vec<_> = bindings
            .iter()
            .enumerate()
            .map(|(i, b)| {
                vk::DescriptorSetLayoutBinding::default()
                    .binding(i as u32)
                    .descriptor_type(b.descriptor_type())
                    .descriptor_count(1)
                    .stage_flags(vk::ShaderStageFlags::COMPUTE)
            })
            .collect();
        let set_layout = unsafe {
            dev.create_descriptor_set_layout(
                &vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings),
                None,
            )
        }?;
        let ranges = [vk::PushConstantRange::default()
            .stage_flags(vk::ShaderStageFlags::COMPUTE)
            .offset(0)
            .size(push_constant_size.max(4))];
        let set_layouts = [set_layout];
        let mut layout_info = vk::PipelineLayoutCreateInfo::default().set_layouts(&set_layouts);
        if push_constant_size > 0 {
            layout_info = layout_info.push_constant_ranges(&ranges);
        }
        let layout = match unsafe { dev.create_pipeline_layout(&layout_info, None) } {
            Ok(l) => l,
            Err(e) => {
                unsafe { dev.destroy_descriptor_set_layout(set_layout, None) };
                return Err(e.into());
            }
        };
        let cleanup = |module: Option<vk::ShaderModule>| unsafe {
            if let Some(m) = module {
                dev.destroy_shader_module(m, None);
            }
            dev.destroy_pipeline_layout(layout, None);
            dev.destroy_descriptor_set_layout(set_layout, None);
        };
        let module = match unsafe {
            dev.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(spirv), None)
        } {
            Ok(m) => m,
            Err(e) => {
                cleanup(None);
                return Err(e.into());
            }
        };
        let entries: Vec<vk::SpecializationMapEntry> = specialization
            .iter()
            .enumerate()
            .map(|(i, &(id, _))| {
                vk::SpecializationMapEntry::default()
                    .constant_id(id)
                    .offset(4 * i as u32)
                    .size(4)
            })
            .collect();
        let data: Vec<u8> = specialization
            .iter()
            .flat_map(|&(_, v)| v.to_ne_bytes())
            .collect();
        let spec_info = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(&data);
        let mut stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(c"main");
        if !specialization.is_empty() {
            stage = stage.specialization_info(&spec_info);
        }
        let info = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(layout)];
        let pipeline =
            unsafe { dev.create_compute_pipelines(vk::PipelineCache::null(), &info, None) };
        unsafe { dev.destroy_shader_module(module, None) };
        let pipeline = match pipeline {
            Ok(p) => p[0],
            Err((_, e)) => {
                cleanup(None);
                return Err(e.into());
            }
        };
        ctx.set_name(pipeline, name);
        Ok(ComputePipeline {
            ctx: ctx.clone(),
            name: name.to_string(),
            pipeline,
            layout,
            set_layout,
            bindings: bindings.to_vec(),
            push_constant_size,
            local_size,
        })
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        unsafe {
            self.ctx.device.destroy_pipeline(self.pipeline, None);
            self.ctx.device.destroy_pipeline_layout(self.layout, None);
            self.ctx
                .device
                .destroy_descriptor_set_layout(self.set_layout, None);
        }
    }
}

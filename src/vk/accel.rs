//! Bottom- and top-level acceleration structures (VK_KHR_acceleration_structure).

use std::sync::Arc;

use ash::vk;

use super::memory::{Buffer, MemoryKind};
use super::{Context, VkError};

/// An acceleration structure and the buffer holding it; dropping it frees both.
pub struct AccelStructure {
    ctx: Arc<Context>,
    pub raw: vk::AccelerationStructureKHR,
    pub address: vk::DeviceAddress,
    _storage: Buffer,
}

impl Drop for AccelStructure {
    fn drop(&mut self) {
        if let Some(a) = &self.ctx.accel {
            unsafe { a.destroy_acceleration_structure(self.raw, None) };
        }
    }
}

/// One triangle mesh as a bottom-level structure, with the input buffers it was built
/// from (kept alive with it).
pub struct Blas {
    pub accel: AccelStructure,
    _inputs: Vec<Buffer>,
}

/// A top-level structure over instances of [`Blas`]es, each with the identity transform
/// and a custom index (the shader adds it to the primitive index, so triangles of all
/// instances share one index space).
pub struct Tlas {
    pub accel: AccelStructure,
    _instances: Buffer,
}

const AS_ALIGNMENT: u64 = 256;

fn build_one(
    ctx: &Arc<Context>,
    name: &str,
    ty: vk::AccelerationStructureTypeKHR,
    geometry: vk::AccelerationStructureGeometryKHR<'_>,
    prim_count: u32,
) -> Result<AccelStructure, VkError> {
    let accel = ctx.accel.as_ref().ok_or(VkError::RayQueryUnavailable)?;
    let geometries = [geometry];
    let mut build = vk::AccelerationStructureBuildGeometryInfoKHR::default()
        .ty(ty)
        .flags(vk::BuildAccelerationStructureFlagsKHR::PREFER_FAST_TRACE)
        .mode(vk::BuildAccelerationStructureModeKHR::BUILD)
        .geometries(&geometries);
    let mut sizes = vk::AccelerationStructureBuildSizesInfoKHR::default();
    unsafe {
        accel.get_acceleration_structure_build_sizes(
            vk::AccelerationStructureBuildTypeKHR::DEVICE,
            &build,
            &[prim_count],
            &mut sizes,
        )
    };
    let storage = Buffer::with_alignment(
        ctx,
        &format!("{name} storage"),
        sizes.acceleration_structure_size,
        vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        MemoryKind::Device,
        AS_ALIGNMENT,
    )?;
    let info = vk::AccelerationStructureCreateInfoKHR::default()
        .buffer(storage.raw)
        .size(sizes.acceleration_structure_size)
        .ty(ty);
    let raw = unsafe { accel.create_acceleration_structure(&info, None) }?;
    ctx.set_name(raw, name);
    let address = unsafe {
        accel.get_acceleration_structure_device_address(
            &vk::AccelerationStructureDeviceAddressInfoKHR::default().acceleration_structure(raw),
        )
    };
    let out = AccelStructure {
        ctx: ctx.clone(),
        raw,
        address,
        _storage: storage,
    };
    let mut as_props = vk::PhysicalDeviceAccelerationStructurePropertiesKHR::default();
    let mut props = vk::PhysicalDeviceProperties2::default().push_next(&mut as_props);
    unsafe {
        ctx.instance
            .get_physical_device_properties2(ctx.physical, &mut props)
    };
    let scratch_align =
        (as_props.min_acceleration_structure_scratch_offset_alignment as u64).max(AS_ALIGNMENT);
    let scratch = Buffer::with_alignment(
        ctx,
        &format!("{name} scratch"),
        sizes.build_scratch_size,
        vk::BufferUsageFlags::STORAGE_BUFFER | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS,
        MemoryKind::Device,
        scratch_align,
    )?;
    build = build
        .dst_acceleration_structure(raw)
        .scratch_data(vk::DeviceOrHostAddressKHR {
            device_address: scratch.device_address(),
        });
    let range = [vk::AccelerationStructureBuildRangeInfoKHR::default().primitive_count(prim_count)];
    let ranges: [&[vk::AccelerationStructureBuildRangeInfoKHR]; 1] = [&range];
    ctx.submit_and_wait(|cb| {
        ctx.begin_label(cb, name);
        unsafe {
            accel.cmd_build_acceleration_structures(cb, std::slice::from_ref(&build), &ranges)
        };
        let barrier = vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_WRITE_KHR)
            .dst_access_mask(vk::AccessFlags::ACCELERATION_STRUCTURE_READ_KHR);
        unsafe {
            ctx.device.cmd_pipeline_barrier(
                cb,
                vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR,
                vk::PipelineStageFlags::ACCELERATION_STRUCTURE_BUILD_KHR
                    | vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::DependencyFlags::empty(),
                &[barrier],
                &[],
                &[],
            )
        };
        ctx.end_label(cb);
        Ok(())
    })?;
    Ok(out)
}

const INPUT_USAGE: vk::BufferUsageFlags = vk::BufferUsageFlags::from_raw(
    vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR.as_raw()
        | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS.as_raw(),
);

impl Blas {
    pub fn build(
        ctx: &Arc<Context>,
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
    ) -> Result<Self, VkError> {
        let vb = Buffer::from_slice(ctx, "blas vertices", positions, INPUT_USAGE)?;
        let ib = Buffer::from_slice(ctx, "blas indices", triangles, INPUT_USAGE)?;
        let tri = vk::AccelerationStructureGeometryTrianglesDataKHR::default()
            .vertex_format(vk::Format::R32G32B32_SFLOAT)
            .vertex_data(vk::DeviceOrHostAddressConstKHR {
                device_address: vb.device_address(),
            })
            .vertex_stride(12)
            .max_vertex(positions.len().saturating_sub(1) as u32)
            .index_type(vk::IndexType::UINT32)
            .index_data(vk::DeviceOrHostAddressConstKHR {
                device_address: ib.device_address(),
            });
        let geom = vk::AccelerationStructureGeometryKHR::default()
            .geometry_type(vk::GeometryTypeKHR::TRIANGLES)
            .geometry(vk::AccelerationStructureGeometryDataKHR { triangles: tri })
            .flags(vk::GeometryFlagsKHR::OPAQUE);
        let accel = build_one(
            ctx,
            "blas",
            vk::AccelerationStructureTypeKHR::BOTTOM_LEVEL,
            geom,
            triangles.len() as u32,
        )?;
        Ok(Blas {
            accel,
            _inputs: vec![vb, ib],
        })
    }
}

impl Tlas {
    /// Instances `(blas, custom index, mask)`; the custom index is 24 bits, the mask is
    /// what a ray query's cull mask selects (glsl/common/trace.glsl: the object 0x01, the
    /// view's lights 0x02).
    pub fn build(ctx: &Arc<Context>, instances: &[(&Blas, u32, u8)]) -> Result<Self, VkError> {
        let mut bytes: Vec<u8> = Vec::with_capacity(instances.len() * 64);
        for &(blas, index, mask) in instances {
            if index >= 1 << 24 {
                return Err(VkError::Other(format!(
                    "instance custom index {index} does not fit in 24 bits"
                )));
            }
            let instance = vk::AccelerationStructureInstanceKHR {
                transform: vk::TransformMatrixKHR {
                    matrix: [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],
                },
                instance_custom_index_and_mask: vk::Packed24_8::new(index, mask),
                instance_shader_binding_table_record_offset_and_flags: vk::Packed24_8::new(
                    0,
                    vk::GeometryInstanceFlagsKHR::TRIANGLE_FACING_CULL_DISABLE.as_raw() as u8,
                ),
                acceleration_structure_reference: vk::AccelerationStructureReferenceKHR {
                    device_handle: blas.accel.address,
                },
            };
            // SAFETY: AccelerationStructureInstanceKHR is a plain repr(C) struct of 64 bytes.
            bytes.extend_from_slice(unsafe {
                std::slice::from_raw_parts(
                    (&instance as *const vk::AccelerationStructureInstanceKHR).cast::<u8>(),
                    std::mem::size_of::<vk::AccelerationStructureInstanceKHR>(),
                )
            });
        }
        let buf = Buffer::from_slice(ctx, "tlas instances", &bytes, INPUT_USAGE)?;
        let inst_data = vk::AccelerationStructureGeometryInstancesDataKHR::default()
            .array_of_pointers(false)
            .data(vk::DeviceOrHostAddressConstKHR {
                device_address: buf.device_address(),
            });
        let geom = vk::AccelerationStructureGeometryKHR::default()
            .geometry_type(vk::GeometryTypeKHR::INSTANCES)
            .geometry(vk::AccelerationStructureGeometryDataKHR {
                instances: inst_data,
            })
            .flags(vk::GeometryFlagsKHR::OPAQUE);
        let accel = build_one(
            ctx,
            "tlas",
            vk::AccelerationStructureTypeKHR::TOP_LEVEL,
            geom,
            instances.len() as u32,
        )?;
        Ok(Tlas {
            accel,
            _instances: buf,
        })
    }
}

//! Buffers backed by gpu-allocator, each freeing itself on drop.

use std::sync::Arc;

use ash::vk;
use gpu_allocator::MemoryLocation;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};

use super::{Context, VkError};

/// Where a buffer's memory lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemoryKind {
    /// Device memory the GPU reads and writes fastest; not necessarily mappable.
    Device,
    /// Host-written, GPU-read (uploads, small per-frame data).
    Upload,
    /// GPU-written, host-read (readback).
    Readback,
}

impl MemoryKind {
    fn location(self) -> MemoryLocation {
        match self {
            MemoryKind::Device => MemoryLocation::GpuOnly,
            MemoryKind::Upload => MemoryLocation::CpuToGpu,
            MemoryKind::Readback => MemoryLocation::GpuToCpu,
        }
    }
}

/// A Vulkan buffer and its memory. Dropping it frees both.
pub struct Buffer {
    ctx: Arc<Context>,
    pub raw: vk::Buffer,
    pub size: u64,
    pub name: String,
    allocation: Option<Allocation>,
}

impl Buffer {
    pub fn new(
        ctx: &Arc<Context>,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        kind: MemoryKind,
    ) -> Result<Buffer, VkError> {
        Self::with_alignment(ctx, name, size, usage, kind, 0)
    }

    /// Like [`Buffer::new`], with a minimum alignment (acceleration-structure storage and
    /// scratch need more than the driver's memory requirements say on some drivers).
    pub fn with_alignment(
        ctx: &Arc<Context>,
        name: &str,
        size: u64,
        mut usage: vk::BufferUsageFlags,
        kind: MemoryKind,
        alignment: u64,
    ) -> Result<Buffer, VkError> {
        let size = size.max(4);
        if !ctx.info.ray_query_enabled {
            usage &= !vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        }
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let raw = unsafe { ctx.device.create_buffer(&info, None) }?;
        let mut req = unsafe { ctx.device.get_buffer_memory_requirements(raw) };
        req.alignment = req.alignment.max(alignment);
        let alloc = ctx
            .allocator
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .allocate(&AllocationCreateDesc {
                name,
                requirements: req,
                location: kind.location(),
                linear: true,
                allocation_scheme: AllocationScheme::GpuAllocatorManaged,
            });
        let alloc = match alloc {
            Ok(a) => a,
            Err(e) => {
                unsafe { ctx.device.destroy_buffer(raw, None) };
                return Err(e.into());
            }
        };
        if let Err(e) = unsafe {
            ctx.device
                .bind_buffer_memory(raw, alloc.memory(), alloc.offset())
        } {
            unsafe { ctx.device.destroy_buffer(raw, None) };
            let _ = ctx
                .allocator
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .free(alloc);
            return Err(e.into());
        }
        ctx.set_name(raw, name);
        Ok(Buffer {
            ctx: ctx.clone(),
            raw,
            size,
            name: name.to_string(),
            allocation: Some(alloc),
        })
    }

    /// A GPU-readable buffer holding `data`. Uses a staging copy when upload memory is not
    /// what the GPU reads fastest is not worth it here: our uploads are read a few times.
    pub fn from_slice<T: bytemuck::Pod>(
        ctx: &Arc<Context>,
        name: &str,
        data: &[T],
        usage: vk::BufferUsageFlags,
    ) -> Result<Buffer, VkError> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let mut b = Buffer::new(ctx, name, bytes.len() as u64, usage, MemoryKind::Upload)?;
        b.write(0, bytes)?;
        Ok(b)
    }

    /// Copies `bytes` into a mapped buffer at `offset`.
    pub fn write(&mut self, offset: usize, bytes: &[u8]) -> Result<(), VkError> {
        let name = self.name.clone();
        let slice = self
            .allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .ok_or(VkError::NotMappable(name))?;
        slice[offset..offset + bytes.len()].copy_from_slice(bytes);
        Ok(())
    }

    /// Reads a mapped buffer (call after the GPU work writing it has completed).
    pub fn read<T: bytemuck::Pod>(&self) -> Result<Vec<T>, VkError> {
        let slice = self
            .allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .ok_or_else(|| VkError::NotMappable(self.name.clone()))?;
        let n = slice.len() / std::mem::size_of::<T>();
        let n = n.min(self.size as usize / std::mem::size_of::<T>());
        Ok(bytemuck::pod_collect_to_vec(
            &slice[..n * std::mem::size_of::<T>()],
        ))
    }

    pub fn device_address(&self) -> vk::DeviceAddress {
        let info = vk::BufferDeviceAddressInfo::default().buffer(self.raw);
        unsafe { self.ctx.device.get_buffer_device_address(&info) }
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        unsafe { self.ctx.device.destroy_buffer(self.raw, None) };
        if let Some(a) = self.allocation.take() {
            let _ = self
                .ctx
                .allocator
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .free(a);
        }
    }
}

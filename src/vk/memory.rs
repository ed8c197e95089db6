//! Buffers backed by gpu-allocator, each freeing itself on drop.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

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

/// The memory this process holds in live buffers and images on one Vulkan device (every
/// allocation of every context on it: [`Context::beside`] shares the count), as the
/// allocator handed it out: what a leak of GPU resources would grow. Read with
/// [`Context::memory_in_use`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MemoryInUse {
    /// Live allocations (one per buffer or image).
    pub allocations: u64,
    /// Their sizes summed, bytes.
    pub bytes: u64,
}

/// The live allocations' count and bytes of one device, updated by every allocation and
/// free ([`MemoryInUse`]).
#[derive(Debug, Default)]
pub(crate) struct MemoryCounter {
    allocations: AtomicU64,
    bytes: AtomicU64,
}

impl MemoryCounter {
    pub(crate) fn get(&self) -> MemoryInUse {
        MemoryInUse {
            allocations: self.allocations.load(Ordering::Relaxed),
            bytes: self.bytes.load(Ordering::Relaxed),
        }
    }

    fn add(&self, bytes: u64) {
        self.allocations.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(bytes, Ordering::Relaxed);
    }

    fn sub(&self, bytes: u64) {
        self.allocations.fetch_sub(1, Ordering::Relaxed);
        self.bytes.fetch_sub(bytes, Ordering::Relaxed);
    }
}

/// Allocates memory for a resource and binds it with `bind`; on a bind failure the
/// memory is freed again (the caller destroys the resource).
fn allocate_bound(
    ctx: &Context,
    name: &str,
    requirements: vk::MemoryRequirements,
    location: MemoryLocation,
    linear: bool,
    bind: impl FnOnce(&Allocation) -> ash::prelude::VkResult<()>,
) -> Result<Allocation, VkError> {
    let alloc = ctx
        .allocator
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear,
            allocation_scheme: AllocationScheme::GpuAllocatorManaged,
        })?;
    ctx.memory.add(alloc.size());
    if let Err(e) = bind(&alloc) {
        free_allocation(ctx, alloc);
        return Err(e.into());
    }
    Ok(alloc)
}

/// Returns an allocation to the allocator (a failure there leaks at worst, so it is not
/// reported from drops and error paths).
fn free_allocation(ctx: &Context, alloc: Allocation) {
    ctx.memory.sub(alloc.size());
    let _ = ctx
        .allocator
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .free(alloc);
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
        // Every storage buffer has a device address where the device offers them: the
        // software traversal and the path tracer read theirs through it.
        if !ctx.info.buffer_device_address {
            usage &= !vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        } else if usage.contains(vk::BufferUsageFlags::STORAGE_BUFFER) {
            usage |= vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        }
        let info = vk::BufferCreateInfo::default()
            .size(size)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        let raw = unsafe { ctx.device.create_buffer(&info, None) }?;
        let mut req = unsafe { ctx.device.get_buffer_memory_requirements(raw) };
        req.alignment = req.alignment.max(alignment);
        let alloc = allocate_bound(ctx, name, req, kind.location(), true, |alloc| unsafe {
            ctx.device
                .bind_buffer_memory(raw, alloc.memory(), alloc.offset())
        })
        .inspect_err(|_| unsafe { ctx.device.destroy_buffer(raw, None) })?;
        ctx.set_name(raw, name);
        Ok(Buffer {
            ctx: ctx.clone(),
            raw,
            size,
            name: name.to_string(),
            allocation: Some(alloc),
        })
    }

    /// A buffer of `size` bytes the GPU reads many times (a slope map's texels), in the
    /// memory it reads fastest: device-local memory, filled by `fill` in place where the
    /// host can map it (lavapipe: all its memory; GPUs whose whole memory is mappable),
    /// else through a staging buffer and a copy on `ctx`'s queue, waited for. (Upload
    /// memory, [`Buffer::from_slice`], may be system memory on a discrete GPU:
    /// gpu-allocator falls back to it when the device-local mappable heap is small, and
    /// the GPU would then read it across the bus at every access.)
    pub fn resident<E: From<VkError>>(
        ctx: &Arc<Context>,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        fill: impl FnOnce(&mut [u8]) -> Result<(), E>,
    ) -> Result<Buffer, E> {
        Self::resident_via(ctx, name, size, usage, false, fill)
    }

    /// [`Buffer::resident`]; `staged`: through the staging copy even where the
    /// device-local memory is mappable (tests: that path on lavapipe).
    pub fn resident_via<E: From<VkError>>(
        ctx: &Arc<Context>,
        name: &str,
        size: u64,
        usage: vk::BufferUsageFlags,
        staged: bool,
        fill: impl FnOnce(&mut [u8]) -> Result<(), E>,
    ) -> Result<Buffer, E> {
        let usage = usage | vk::BufferUsageFlags::TRANSFER_DST;
        let mut b = Buffer::new(ctx, name, size, usage, MemoryKind::Device)?;
        if !staged && let Ok(bytes) = b.mapped_mut() {
            fill(bytes)?;
            return Ok(b);
        }
        let src = vk::BufferUsageFlags::TRANSFER_SRC;
        let mut staging = Buffer::new(
            ctx,
            &format!("{name} (staging)"),
            b.size,
            src,
            MemoryKind::Upload,
        )?;
        fill(staging.mapped_mut()?)?;
        ctx.submit_and_wait(|cb| {
            let region = [vk::BufferCopy::default().size(b.size)];
            let barrier = [vk::BufferMemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                .dst_access_mask(vk::AccessFlags::SHADER_READ)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .buffer(b.raw)
                .offset(0)
                .size(vk::WHOLE_SIZE)];
            unsafe {
                ctx.device.cmd_copy_buffer(cb, staging.raw, b.raw, &region);
                ctx.device.cmd_pipeline_barrier(
                    cb,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::COMPUTE_SHADER,
                    vk::DependencyFlags::empty(),
                    &[],
                    &barrier,
                    &[],
                )
            };
            Ok(())
        })?;
        Ok(b)
    }

    /// A GPU-readable buffer holding `data`, in upload memory (host-visible): for data
    /// the GPU reads a few times; see [`Buffer::resident`] for data it reads often.
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
        self.mapped_mut()?[offset..offset + bytes.len()].copy_from_slice(bytes);
        Ok(())
    }

    /// A mapped buffer's bytes (its `size`), to be written in place (e.g. values made
    /// straight into it instead of into a vector that is then copied).
    pub fn mapped_mut(&mut self) -> Result<&mut [u8], VkError> {
        let size = self.size as usize;
        let slice = self
            .allocation
            .as_mut()
            .and_then(|a| a.mapped_slice_mut())
            .ok_or_else(|| VkError::NotMappable(self.name.clone()))?;
        let n = size.min(slice.len());
        Ok(&mut slice[..n])
    }

    /// Reads a mapped buffer (call after the GPU work writing it has completed).
    pub fn read<T: bytemuck::Pod>(&self) -> Result<Vec<T>, VkError> {
        Ok(bytemuck::pod_collect_to_vec(self.mapped_values::<T>()?))
    }

    /// [`Buffer::read`] into `out` (its length set to the buffer's values), so that a
    /// caller can reuse one vector's memory for many reads.
    pub fn read_into<T: bytemuck::Pod>(&self, out: &mut Vec<T>) -> Result<(), VkError> {
        let bytes = self.mapped_values::<T>()?;
        out.resize(bytes.len() / std::mem::size_of::<T>(), T::zeroed()); // all overwritten
        bytemuck::cast_slice_mut::<T, u8>(out).copy_from_slice(bytes);
        Ok(())
    }

    /// The mapped bytes of the whole values of `T` the buffer holds.
    fn mapped_values<T: bytemuck::Pod>(&self) -> Result<&[u8], VkError> {
        let slice = self
            .allocation
            .as_ref()
            .and_then(|a| a.mapped_slice())
            .ok_or_else(|| VkError::NotMappable(self.name.clone()))?;
        let n = slice.len() / std::mem::size_of::<T>();
        let n = n.min(self.size as usize / std::mem::size_of::<T>());
        Ok(&slice[..n * std::mem::size_of::<T>()])
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
            free_allocation(&self.ctx, a);
        }
    }
}

/// A 2D image with its memory and a full view. Dropping it frees all three.
pub struct Image {
    ctx: Arc<Context>,
    pub raw: vk::Image,
    pub view: vk::ImageView,
    pub format: vk::Format,
    pub extent: vk::Extent2D,
    allocation: Option<Allocation>,
}

impl Image {
    /// A device-local, optimally tiled 2D image (one mip level, one layer), in layout
    /// UNDEFINED; [`Image::transition`] moves it to the layout a pass needs.
    pub fn new_2d(
        ctx: &Arc<Context>,
        name: &str,
        width: u32,
        height: u32,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
    ) -> Result<Image, VkError> {
        let extent = vk::Extent2D { width, height };
        let info = vk::ImageCreateInfo::default()
            .image_type(vk::ImageType::TYPE_2D)
            .format(format)
            .extent(vk::Extent3D {
                width,
                height,
                depth: 1,
            })
            .mip_levels(1)
            .array_layers(1)
            .samples(vk::SampleCountFlags::TYPE_1)
            .tiling(vk::ImageTiling::OPTIMAL)
            .usage(usage)
            .sharing_mode(vk::SharingMode::EXCLUSIVE)
            .initial_layout(vk::ImageLayout::UNDEFINED);
        let raw = unsafe { ctx.device.create_image(&info, None) }?;
        let req = unsafe { ctx.device.get_image_memory_requirements(raw) };
        let alloc = allocate_bound(
            ctx,
            name,
            req,
            MemoryLocation::GpuOnly,
            false,
            |alloc| unsafe {
                ctx.device
                    .bind_image_memory(raw, alloc.memory(), alloc.offset())
            },
        )
        .inspect_err(|_| unsafe { ctx.device.destroy_image(raw, None) })?;
        let view_info = vk::ImageViewCreateInfo::default()
            .image(raw)
            .view_type(vk::ImageViewType::TYPE_2D)
            .format(format)
            .subresource_range(Self::full_range());
        let view = match unsafe { ctx.device.create_image_view(&view_info, None) } {
            Ok(v) => v,
            Err(e) => {
                unsafe { ctx.device.destroy_image(raw, None) };
                free_allocation(ctx, alloc);
                return Err(e.into());
            }
        };
        ctx.set_name(raw, name);
        Ok(Image {
            ctx: ctx.clone(),
            raw,
            view,
            format,
            extent,
            allocation: Some(alloc),
        })
    }

    fn full_range() -> vk::ImageSubresourceRange {
        vk::ImageSubresourceRange::default()
            .aspect_mask(vk::ImageAspectFlags::COLOR)
            .level_count(1)
            .layer_count(1)
    }

    /// Records a layout transition with a full barrier between the given stages.
    pub fn transition(
        &self,
        cb: vk::CommandBuffer,
        from: (vk::ImageLayout, vk::PipelineStageFlags, vk::AccessFlags),
        to: (vk::ImageLayout, vk::PipelineStageFlags, vk::AccessFlags),
    ) {
        let barrier = vk::ImageMemoryBarrier::default()
            .old_layout(from.0)
            .new_layout(to.0)
            .src_access_mask(from.2)
            .dst_access_mask(to.2)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(self.raw)
            .subresource_range(Self::full_range());
        unsafe {
            self.ctx.device.cmd_pipeline_barrier(
                cb,
                from.1,
                to.1,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[barrier],
            )
        };
    }

    /// Records a copy of the whole image (in TRANSFER_SRC_OPTIMAL) into `dst`.
    pub fn copy_to_buffer(&self, cb: vk::CommandBuffer, dst: &Buffer) {
        let region = [self.buffer_region()];
        unsafe {
            self.ctx.device.cmd_copy_image_to_buffer(
                cb,
                self.raw,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.raw,
                &region,
            )
        };
    }

    /// Records a copy of `src` into the whole image (in TRANSFER_DST_OPTIMAL).
    pub fn copy_from_buffer(&self, cb: vk::CommandBuffer, src: &Buffer) {
        let region = [self.buffer_region()];
        unsafe {
            self.ctx.device.cmd_copy_buffer_to_image(
                cb,
                src.raw,
                self.raw,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &region,
            )
        };
    }

    fn buffer_region(&self) -> vk::BufferImageCopy {
        vk::BufferImageCopy::default()
            .image_subresource(
                vk::ImageSubresourceLayers::default()
                    .aspect_mask(vk::ImageAspectFlags::COLOR)
                    .layer_count(1),
            )
            .image_extent(vk::Extent3D {
                width: self.extent.width,
                height: self.extent.height,
                depth: 1,
            })
    }
}

impl Drop for Image {
    fn drop(&mut self) {
        unsafe {
            self.ctx.device.destroy_image_view(self.view, None);
            self.ctx.device.destroy_image(self.raw, None);
        }
        if let Some(a) = self.allocation.take() {
            free_allocation(&self.ctx, a);
        }
    }
}

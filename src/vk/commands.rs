//! Command buffer recording and synchronous submission.

use ash::vk;

use super::{Context, VkError};

impl Context {
    /// Records commands with `record`, submits them, and waits for completion.
    pub fn submit_and_wait<R>(
        &self,
        record: impl FnOnce(vk::CommandBuffer) -> Result<R, VkError>,
    ) -> Result<R, VkError> {
        let pool = self.command_pool.lock().unwrap_or_else(|p| p.into_inner());
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(*pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        let cb = unsafe { self.device.allocate_command_buffers(&alloc) }?[0];
        let fence = unsafe {
            self.device
                .create_fence(&vk::FenceCreateInfo::default(), None)
        };
        let fence = match fence {
            Ok(f) => f,
            Err(e) => {
                unsafe { self.device.free_command_buffers(*pool, &[cb]) };
                return Err(e.into());
            }
        };
        let result = (|| {
            let begin = vk::CommandBufferBeginInfo::default()
                .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            unsafe { self.device.begin_command_buffer(cb, &begin) }?;
            let r = record(cb)?;
            unsafe { self.device.end_command_buffer(cb) }?;
            let cbs = [cb];
            let submit = [vk::SubmitInfo::default().command_buffers(&cbs)];
            unsafe {
                {
                    let _queue = self.queue_lock.lock().unwrap_or_else(|p| p.into_inner());
                    self.device.queue_submit(self.queue, &submit, fence)?;
                }
                self.device.wait_for_fences(&[fence], true, u64::MAX)?;
            }
            Ok(r)
        })();
        unsafe {
            self.device.destroy_fence(fence, None);
            self.device.free_command_buffers(*pool, &[cb]);
        }
        result
    }

    /// Opens a debug label region (shows in captures and validation messages).
    pub fn begin_label(&self, cb: vk::CommandBuffer, name: &str) {
        if let (Some(du), Ok(n)) = (&self.debug_utils, std::ffi::CString::new(name)) {
            let label = vk::DebugUtilsLabelEXT::default().label_name(&n);
            unsafe { du.cmd_begin_debug_utils_label(cb, &label) };
        }
    }

    pub fn end_label(&self, cb: vk::CommandBuffer) {
        if let Some(du) = &self.debug_utils {
            unsafe { du.cmd_end_debug_utils_label(cb) };
        }
    }
}

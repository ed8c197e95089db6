//! Vulkan instance, device choice, logical device, queues and the validation log.

use std::ffi::{CStr, CString, c_void};
use std::mem::ManuallyDrop;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use ash::vk;
use gpu_allocator::vulkan::{Allocator, AllocatorCreateDesc};

use super::VkError;
use super::memory::{MemoryCounter, MemoryInUse};

/// What the caller needs from the device.
#[derive(Clone, Debug, Default)]
pub struct ContextOptions {
    /// Enable the Khronos validation layer and collect its messages. Also turned on by
    /// the environment variable `SYNOSIS_VALIDATION=1`.
    pub validation: bool,
    /// Enable acceleration structures and ray query when the device has them.
    pub ray_query: bool,
}

/// One memory heap of the device.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MemoryHeap {
    pub size_bytes: u64,
    pub device_local: bool,
    /// Some memory type of the heap can be mapped by the host: a device-local one that is
    /// (a whole GPU's memory with resizable BAR; 256 MB without) takes the upload buffers
    /// (`MemoryKind::Upload`) and lets `Buffer::resident` fill its buffers in place.
    pub host_visible: bool,
}

/// What `synosis info` prints and what backends consult.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DeviceInfo {
    pub name: String,
    pub device_type: String,
    pub driver_name: String,
    pub driver_info: String,
    pub vulkan_version: String,
    pub ray_query_supported: bool,
    pub ray_query_enabled: bool,
    /// Buffer device addresses (`bufferDeviceAddress`, core in Vulkan 1.2 and required
    /// from 1.3) are on: the path tracer and the software trace backends read their
    /// buffers through them (ray query needs them too).
    pub buffer_device_address: bool,
    /// 64-bit integers in shaders (`shaderInt64`) are on: the wide software traversal's
    /// stack entries are 64-bit words.
    pub shader_int64: bool,
    /// Subgroup arithmetic (`subgroupMax`) in compute shaders (Vulkan 1.1 subgroup
    /// properties): the path tracer makes the extra camera rays' loops lane-uniform with
    /// it (glsl/common/analytic_light.glsl `recorded_loop2`).
    pub subgroup_arithmetic: bool,
    pub is_cpu: bool,
    /// How lavapipe's vector width was chosen for this process (`vk::lanes`; read by
    /// lavapipe only).
    pub cpu_lanes: super::LaneWidth,
    /// The shader-cache folder `vk::lanes` set for that width (None: Mesa's own, at the
    /// driver's default width).
    pub cpu_shader_cache: Option<String>,
    pub timestamp_period_ns: f32,
    pub timestamps_supported: bool,
    /// How many queues of the chosen family the device was opened with (at most
    /// [`MAX_QUEUES`]).
    pub queue_count: u32,
    pub max_storage_buffer_range: u32,
    /// Texels a texel buffer view may span (the software BVH's levels, the shading
    /// triangles and the slope maps' headers are read as texel buffers of 16-byte
    /// texels: [`DeviceInfo::fits_texel_buffer`]).
    pub max_texel_buffer_elements: u32,
    pub max_workgroup_count: [u32; 3],
    pub memory_heaps: Vec<MemoryHeap>,
    pub validation: bool,
}

#[cfg(test)]
impl DeviceInfo {
    /// A discrete GPU with every feature the renderer needs and no ray query, for unit
    /// tests of what a device's features decide (set a field to take one away).
    pub(crate) fn test_device() -> DeviceInfo {
        DeviceInfo {
            name: "test device".into(),
            device_type: "DISCRETE_GPU".into(),
            driver_name: String::new(),
            driver_info: String::new(),
            vulkan_version: "1.2.0".into(),
            ray_query_supported: false,
            ray_query_enabled: false,
            buffer_device_address: true,
            shader_int64: true,
            subgroup_arithmetic: true,
            is_cpu: false,
            cpu_lanes: super::LaneWidth::Driver,
            cpu_shader_cache: None,
            timestamp_period_ns: 1.0,
            timestamps_supported: true,
            queue_count: 1,
            max_storage_buffer_range: u32::MAX,
            max_texel_buffer_elements: u32::MAX,
            max_workgroup_count: [65_535; 3],
            memory_heaps: Vec::new(),
            validation: false,
        }
    }
}

impl DeviceInfo {
    /// Whether `bytes` of `what`, read as one texel buffer of 16-byte texels
    /// (`TEXEL_BUFFER_FORMAT`), fit the device's `maxTexelBufferElements`; if not, an
    /// error naming them, the limit and `cause` (what the user can change).
    pub fn fits_texel_buffer(&self, what: &str, bytes: usize, cause: &str) -> Result<(), VkError> {
        let max = self.max_texel_buffer_elements as usize;
        if bytes / 16 > max {
            return Err(VkError::Other(format!(
                "the {what} take {} texels of 16 bytes; the device's texel buffers hold at most {max} (maxTexelBufferElements): {cause}",
                bytes / 16
            )));
        }
        Ok(())
    }
}

/// A validation or driver message caught by the debug messenger.
#[derive(Clone, Debug)]
pub struct ValidationMessage {
    pub error: bool,
    pub text: String,
}

/// Every message the validation layer sent, so a test can fail on any error.
#[derive(Default, Debug)]
pub struct ValidationLog {
    messages: Mutex<Vec<ValidationMessage>>,
}

impl ValidationLog {
    pub fn errors(&self) -> Vec<String> {
        self.lock()
            .iter()
            .filter(|m| m.error)
            .map(|m| m.text.clone())
            .collect()
    }
    pub fn all(&self) -> Vec<ValidationMessage> {
        self.lock().clone()
    }
    fn lock(&self) -> std::sync::MutexGuard<'_, Vec<ValidationMessage>> {
        self.messages.lock().unwrap_or_else(|p| p.into_inner())
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    kind: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: `user` is the ValidationLog the Context keeps alive for the messenger's
    // lifetime; `data` is valid for this call per the Vulkan spec.
    unsafe {
        let log = &*(user as *const ValidationLog);
        let text = if data.is_null() || (*data).p_message.is_null() {
            String::from("(no message)")
        } else {
            CStr::from_ptr((*data).p_message)
                .to_string_lossy()
                .into_owned()
        };
        let error = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::ERROR);
        let warning = severity.contains(vk::DebugUtilsMessageSeverityFlagsEXT::WARNING);
        if error || (warning && kind.contains(vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION)) {
            log.lock().push(ValidationMessage {
                error,
                text: text.clone(),
            });
        }
        if error {
            eprintln!("vulkan validation error: {text}");
        }
    }
    vk::FALSE
}

/// The most queues of the chosen family a device is opened with: contexts made
/// [`Context::beside`] one another take them in turn, so their submissions can run on the
/// GPU side by side (contexts on different devices only take turns).
pub const MAX_QUEUES: u32 = 8;

/// The device's queues of the chosen family, each with the lock its submissions take
/// (contexts beside one another may share a queue when there are more of them than
/// queues; Vulkan wants a queue's submissions externally synchronised).
struct Queues {
    queues: Vec<(vk::Queue, Arc<Mutex<()>>)>,
    /// The queue the next context made beside this device takes (modulo their number).
    next: AtomicUsize,
}

/// The Vulkan device and everything that lives as long as it. Shared as `Arc<Context>`;
/// every resource keeps an `Arc` so the device outlives them. A context made by
/// [`Context::beside`] shares the device of the one it was made from but has its own
/// queue (while the device has one free), memory allocator and command pool.
pub struct Context {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    pub physical: vk::PhysicalDevice,
    pub device: ash::Device,
    pub queue: vk::Queue,
    pub queue_family: u32,
    /// Held while submitting to `queue`.
    pub(crate) queue_lock: Arc<Mutex<()>>,
    /// The device's queues (taken in turn by contexts made beside this one).
    queues: Arc<Queues>,
    /// The context that owns the device, for one made beside it (kept alive by this).
    owner: Option<Arc<Context>>,
    pub info: DeviceInfo,
    pub accel: Option<ash::khr::acceleration_structure::Device>,
    pub debug_utils: Option<ash::ext::debug_utils::Device>,
    pub validation: Arc<ValidationLog>,
    pub(crate) allocator: ManuallyDrop<Mutex<Allocator>>,
    /// The device's live allocations, shared by the contexts beside one another.
    pub(crate) memory: Arc<MemoryCounter>,
    pub(crate) command_pool: Mutex<vk::CommandPool>,
    /// Names of the pipelines recorded in a dispatch on this context (a warm-up checks
    /// that it ran every pipeline: `render::pipelines::prepare`).
    dispatched: Mutex<std::collections::BTreeSet<String>>,
    debug_instance: Option<ash::ext::debug_utils::Instance>,
    messenger: vk::DebugUtilsMessengerEXT,
}

fn validation_from_env() -> bool {
    matches!(
        std::env::var("SYNOSIS_VALIDATION").as_deref(),
        Ok("1") | Ok("true") | Ok("yes")
    )
}

fn version_string(v: u32) -> String {
    format!(
        "{}.{}.{}",
        vk::api_version_major(v),
        vk::api_version_minor(v),
        vk::api_version_patch(v)
    )
}

fn cstr_field(chars: &[std::ffi::c_char]) -> String {
    // SAFETY: Vulkan fills these fixed-size fields with NUL-terminated strings.
    unsafe { CStr::from_ptr(chars.as_ptr()) }
        .to_string_lossy()
        .into_owned()
}

/// Held while a Vulkan instance and device are made or destroyed: one at a time in the
/// process. Vulkan lets separate instances live on separate threads, but loaders, layers
/// and drivers have had races in exactly these calls when threads make and drop devices
/// at once (test binaries do: each test its own device); a crash of the GPU tests on CI
/// (SIGSEGV, 2026-11-27, not repeated here) is the reason to rule that out. A run makes
/// its contexts once, so the lock is not contended there.
static LIFECYCLE: Mutex<()> = Mutex::new(());

fn lifecycle_lock() -> std::sync::MutexGuard<'static, ()> {
    LIFECYCLE.lock().unwrap_or_else(|p| p.into_inner())
}

impl Context {
    pub fn new(opts: &ContextOptions) -> Result<Arc<Context>, VkError> {
        let _lifecycle = lifecycle_lock();
        // Lavapipe's vector width, before the first driver loads (it reads it then).
        super::lanes::choose();
        // SAFETY: loading the system Vulkan loader; failure is reported as an error.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| VkError::Loader(e.to_string()))?;
        let validation = opts.validation || validation_from_env();

        let layer_props = unsafe { entry.enumerate_instance_layer_properties() }?;
        let validation_layer = c"VK_LAYER_KHRONOS_validation";
        let have_layer = layer_props
            .iter()
            .any(|l| l.layer_name_as_c_str().ok() == Some(validation_layer));
        if validation && !have_layer {
            return Err(VkError::MissingValidationLayer);
        }
        let ext_props = unsafe { entry.enumerate_instance_extension_properties(None) }?;
        let have_debug_utils = ext_props
            .iter()
            .any(|e| e.extension_name_as_c_str().ok() == Some(ash::ext::debug_utils::NAME));

        let app_name = CString::new("synosis").expect("static name has no NUL");
        let app = vk::ApplicationInfo::default()
            .application_name(&app_name)
            .application_version(1)
            .engine_name(&app_name)
            .api_version(vk::API_VERSION_1_2);
        let layers: Vec<*const std::ffi::c_char> = if validation {
            vec![validation_layer.as_ptr()]
        } else {
            vec![]
        };
        let extensions: Vec<*const std::ffi::c_char> = if have_debug_utils {
            vec![ash::ext::debug_utils::NAME.as_ptr()]
        } else {
            vec![]
        };
        let log = Arc::new(ValidationLog::default());
        let mut messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(
                vk::DebugUtilsMessageSeverityFlagsEXT::ERROR
                    | vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
            )
            .message_type(
                vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                    | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                    | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
            )
            .pfn_user_callback(Some(debug_callback))
            .user_data(Arc::as_ptr(&log) as *mut c_void);
        let mut create = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&extensions);
        if have_debug_utils && validation {
            // Also catches messages from instance creation itself.
            create = create.push_next(&mut messenger_info);
        }
        let instance = unsafe { entry.create_instance(&create, None) }?;

        let (debug_instance, messenger) = if have_debug_utils {
            let di = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let m = if validation {
                unsafe { di.create_debug_utils_messenger(&messenger_info, None) }?
            } else {
                vk::DebugUtilsMessengerEXT::null()
            };
            (Some(di), m)
        } else {
            (None, vk::DebugUtilsMessengerEXT::null())
        };

        let result = Self::create_device(&entry, &instance, opts, validation, have_debug_utils);
        let (physical, device, queue_family, info, accel_enabled) = match result {
            Ok(v) => v,
            Err(e) => {
                unsafe {
                    if let Some(di) = &debug_instance
                        && messenger != vk::DebugUtilsMessengerEXT::null()
                    {
                        di.destroy_debug_utils_messenger(messenger, None);
                    }
                    instance.destroy_instance(None);
                }
                return Err(e);
            }
        };
        let queues: Vec<(vk::Queue, Arc<Mutex<()>>)> = (0..info.queue_count)
            .map(|i| {
                let q = unsafe { device.get_device_queue(queue_family, i) };
                (q, Arc::new(Mutex::new(())))
            })
            .collect();
        let (queue, queue_lock) = queues[0].clone();
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: instance.clone(),
            device: device.clone(),
            physical_device: physical,
            debug_settings: Default::default(),
            buffer_device_address: info.buffer_device_address,
            allocation_sizes: Default::default(),
        })?;
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        let command_pool = unsafe { device.create_command_pool(&pool_info, None) }?;
        let accel = accel_enabled
            .then(|| ash::khr::acceleration_structure::Device::new(&instance, &device));
        let debug_utils =
            have_debug_utils.then(|| ash::ext::debug_utils::Device::new(&instance, &device));
        Ok(Arc::new(Context {
            entry,
            instance,
            physical,
            device,
            queue,
            queue_family,
            queue_lock,
            queues: Arc::new(Queues {
                queues,
                next: AtomicUsize::new(1),
            }),
            owner: None,
            info,
            accel,
            debug_utils,
            validation: log,
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            memory: Arc::default(),
            command_pool: Mutex::new(command_pool),
            dispatched: Mutex::default(),
            debug_instance,
            messenger,
        }))
    }

    /// The memory in live buffers and images on this context's device, all the contexts
    /// beside one another on it together ([`MemoryInUse`]).
    pub fn memory_in_use(&self) -> MemoryInUse {
        self.memory.get()
    }

    /// A context on the same device with the device's next queue (the queues are taken
    /// in turn and shared, each submission under its queue's lock, once every one is
    /// taken), its own memory allocator and command pool. Work submitted by contexts on
    /// different queues can run on the GPU at the same time; contexts on separate
    /// devices ([`Context::new`] twice) only take turns. Resources made with it belong
    /// to it, the device's validation log is shared.
    pub fn beside(self: &Arc<Context>) -> Result<Arc<Context>, VkError> {
        let owner = self.owner.clone().unwrap_or_else(|| self.clone());
        let n = owner.queues.queues.len();
        let index = owner.queues.next.fetch_add(1, Ordering::Relaxed) % n;
        let (queue, queue_lock) = owner.queues.queues[index].clone();
        let allocator = Allocator::new(&AllocatorCreateDesc {
            instance: owner.instance.clone(),
            device: owner.device.clone(),
            physical_device: owner.physical,
            debug_settings: Default::default(),
            buffer_device_address: owner.info.buffer_device_address,
            allocation_sizes: Default::default(),
        })?;
        let pool_info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(owner.queue_family)
            .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER);
        let command_pool = unsafe { owner.device.create_command_pool(&pool_info, None) }?;
        Ok(Arc::new(Context {
            entry: owner.entry.clone(),
            instance: owner.instance.clone(),
            physical: owner.physical,
            device: owner.device.clone(),
            queue,
            queue_family: owner.queue_family,
            queue_lock,
            queues: owner.queues.clone(),
            info: owner.info.clone(),
            accel: owner.accel.clone(),
            debug_utils: owner.debug_utils.clone(),
            validation: owner.validation.clone(),
            allocator: ManuallyDrop::new(Mutex::new(allocator)),
            memory: owner.memory.clone(),
            command_pool: Mutex::new(command_pool),
            dispatched: Mutex::default(),
            debug_instance: None,
            messenger: vk::DebugUtilsMessengerEXT::null(),
            owner: Some(owner),
        }))
    }

    #[allow(clippy::type_complexity)]
    fn create_device(
        entry: &ash::Entry,
        instance: &ash::Instance,
        opts: &ContextOptions,
        validation: bool,
        _debug_utils: bool,
    ) -> Result<(vk::PhysicalDevice, ash::Device, u32, DeviceInfo, bool), VkError> {
        let _ = entry;
        let physicals = unsafe { instance.enumerate_physical_devices() }?;
        // Prefer a discrete GPU, then integrated, virtual, and the CPU (lavapipe) last.
        let score = |t: vk::PhysicalDeviceType| match t {
            vk::PhysicalDeviceType::DISCRETE_GPU => 4,
            vk::PhysicalDeviceType::INTEGRATED_GPU => 3,
            vk::PhysicalDeviceType::VIRTUAL_GPU => 2,
            vk::PhysicalDeviceType::CPU => 1,
            _ => 0,
        };
        let mut candidates: Vec<(vk::PhysicalDevice, u32, i32)> = Vec::new();
        for &p in &physicals {
            let props = unsafe { instance.get_physical_device_properties(p) };
            if props.api_version < vk::API_VERSION_1_2 {
                continue;
            }
            let families = unsafe { instance.get_physical_device_queue_family_properties(p) };
            if let Some(q) = families
                .iter()
                .position(|f| f.queue_flags.contains(vk::QueueFlags::COMPUTE))
            {
                candidates.push((p, q as u32, score(props.device_type)));
            }
        }
        if let Ok(want) = std::env::var("SYNOSIS_DEVICE") {
            candidates.retain(|(p, _, _)| {
                let props = unsafe { instance.get_physical_device_properties(*p) };
                cstr_field(&props.device_name)
                    .to_lowercase()
                    .contains(&want.to_lowercase())
            });
        }
        candidates.sort_by_key(|c| -c.2);
        let Some(&(physical, queue_family, _)) = candidates.first() else {
            return Err(VkError::NoDevice);
        };

        let exts = unsafe { instance.enumerate_device_extension_properties(physical) }?;
        let has_ext = |name: &CStr| {
            exts.iter()
                .any(|e| e.extension_name_as_c_str().ok() == Some(name))
        };
        let rq_exts = [
            ash::khr::acceleration_structure::NAME,
            ash::khr::ray_query::NAME,
            ash::khr::deferred_host_operations::NAME,
        ];
        let mut rq_feat = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        let mut as_feat = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        {
            let mut f2 = vk::PhysicalDeviceFeatures2::default().push_next(&mut v12);
            unsafe { instance.get_physical_device_features2(physical, &mut f2) };
        }
        let buffer_device_address = v12.buffer_device_address == vk::TRUE;
        let ray_query_supported = buffer_device_address && rq_exts.iter().all(|e| has_ext(e)) && {
            let mut f2 = vk::PhysicalDeviceFeatures2::default()
                .push_next(&mut rq_feat)
                .push_next(&mut as_feat);
            unsafe { instance.get_physical_device_features2(physical, &mut f2) };
            rq_feat.ray_query == vk::TRUE && as_feat.acceleration_structure == vk::TRUE
        };
        let ray_query_enabled = opts.ray_query && ray_query_supported;

        let mut ext_names: Vec<*const std::ffi::c_char> = Vec::new();
        if ray_query_enabled {
            ext_names.extend(rq_exts.iter().map(|e| e.as_ptr()));
        }
        let families = unsafe { instance.get_physical_device_queue_family_properties(physical) };
        let queue_count = families[queue_family as usize]
            .queue_count
            .clamp(1, MAX_QUEUES);
        let priorities = vec![1.0f32; queue_count as usize];
        let queue_info = [vk::DeviceQueueCreateInfo::default()
            .queue_family_index(queue_family)
            .queue_priorities(&priorities)];
        let mut v12_on = vk::PhysicalDeviceVulkan12Features::default()
            .host_query_reset(true)
            .buffer_device_address(buffer_device_address);
        let mut rq_on = vk::PhysicalDeviceRayQueryFeaturesKHR::default().ray_query(true);
        let mut as_on = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default()
            .acceleration_structure(true);
        // 64-bit integers: the wide software traversal's stack entries are 64-bit words
        // (glsl/common/trace_bvh.glsl).
        let shader_int64 =
            unsafe { instance.get_physical_device_features(physical) }.shader_int64 == vk::TRUE;
        let features = vk::PhysicalDeviceFeatures::default().shader_int64(shader_int64);
        let mut create = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queue_info)
            .enabled_features(&features)
            .enabled_extension_names(&ext_names)
            .push_next(&mut v12_on);
        if ray_query_enabled {
            create = create.push_next(&mut rq_on).push_next(&mut as_on);
        }
        let device = unsafe { instance.create_device(physical, &create, None) }?;

        let mut driver = vk::PhysicalDeviceDriverProperties::default();
        let mut subgroup = vk::PhysicalDeviceSubgroupProperties::default();
        let mut props2 = vk::PhysicalDeviceProperties2::default()
            .push_next(&mut driver)
            .push_next(&mut subgroup);
        unsafe { instance.get_physical_device_properties2(physical, &mut props2) };
        let props = props2.properties;
        let subgroup_arithmetic = subgroup
            .supported_stages
            .contains(vk::ShaderStageFlags::COMPUTE)
            && subgroup
                .supported_operations
                .contains(vk::SubgroupFeatureFlags::ARITHMETIC);
        let mem = unsafe { instance.get_physical_device_memory_properties(physical) };
        let info = DeviceInfo {
            name: cstr_field(&props.device_name),
            device_type: format!("{:?}", props.device_type),
            driver_name: cstr_field(&driver.driver_name),
            driver_info: cstr_field(&driver.driver_info),
            vulkan_version: version_string(props.api_version),
            ray_query_supported,
            ray_query_enabled,
            buffer_device_address,
            shader_int64,
            subgroup_arithmetic,
            is_cpu: props.device_type == vk::PhysicalDeviceType::CPU,
            cpu_lanes: super::lanes::choose(),
            cpu_shader_cache: super::lanes::cache_dir().map(|d| d.display().to_string()),
            timestamp_period_ns: props.limits.timestamp_period,
            timestamps_supported: families[queue_family as usize].timestamp_valid_bits > 0,
            queue_count,
            max_storage_buffer_range: props.limits.max_storage_buffer_range,
            max_texel_buffer_elements: props.limits.max_texel_buffer_elements,
            max_workgroup_count: props.limits.max_compute_work_group_count,
            memory_heaps: mem.memory_heaps[..mem.memory_heap_count as usize]
                .iter()
                .enumerate()
                .map(|(i, h)| MemoryHeap {
                    size_bytes: h.size,
                    device_local: h.flags.contains(vk::MemoryHeapFlags::DEVICE_LOCAL),
                    host_visible: mem.memory_types[..mem.memory_type_count as usize]
                        .iter()
                        .any(|t| {
                            t.heap_index as usize == i
                                && t.property_flags
                                    .contains(vk::MemoryPropertyFlags::HOST_VISIBLE)
                        }),
                })
                .collect(),
            validation,
        };
        Ok((physical, device, queue_family, info, ray_query_enabled))
    }

    /// Gives a Vulkan object a name that shows in validation messages and captures.
    pub fn set_name<H: vk::Handle>(&self, handle: H, name: &str) {
        if let (Some(du), Ok(n)) = (&self.debug_utils, CString::new(name)) {
            let info = vk::DebugUtilsObjectNameInfoEXT::default()
                .object_handle(handle)
                .object_name(&n);
            // Naming is a debugging aid; a failure must not stop rendering.
            let _ = unsafe { du.set_debug_utils_object_name(&info) };
        }
    }

    /// Notes that a dispatch of pipeline `name` was recorded on this context.
    pub(crate) fn note_dispatch(&self, name: &str) {
        let mut d = self.dispatched.lock().unwrap_or_else(|p| p.into_inner());
        if !d.contains(name) {
            d.insert(name.to_owned());
        }
    }

    /// The pipelines (by name, e.g. `path_trace.sw`) recorded in a dispatch on this
    /// context so far.
    pub fn dispatched_pipelines(&self) -> std::collections::BTreeSet<String> {
        self.dispatched
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Validation errors collected so far (empty when validation is off).
    pub fn validation_errors(&self) -> Vec<String> {
        self.validation.errors()
    }

    /// An error naming the first validation error, if the layer reported any: callers
    /// refuse to write output made by invalid Vulkan usage.
    pub fn check_validation(&self) -> Result<(), VkError> {
        let errors = self.validation_errors();
        match errors.first() {
            None => Ok(()),
            Some(first) => Err(VkError::Validation {
                count: errors.len(),
                first: first.clone(),
            }),
        }
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        unsafe {
            // Beside another context, every submission was waited for and the owner
            // (kept alive until this drop ends) destroys the device; the owner waits for
            // the device first.
            let owns_device = self.owner.is_none();
            if owns_device {
                let _ = self.device.device_wait_idle();
            }
            let pool = *self
                .command_pool
                .get_mut()
                .unwrap_or_else(|p| p.into_inner());
            self.device.destroy_command_pool(pool, None);
            // The allocator frees its memory blocks, so it must go before the device.
            ManuallyDrop::drop(&mut self.allocator);
            if !owns_device {
                return;
            }
            let _lifecycle = lifecycle_lock();
            self.device.destroy_device(None);
            if let Some(di) = &self.debug_instance
                && self.messenger != vk::DebugUtilsMessengerEXT::null()
            {
                di.destroy_debug_utils_messenger(self.messenger, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

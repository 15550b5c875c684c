//! Adapter discovery and choice for the wgpu renderer.
//!
//! Owns the wgpu `Instance` set-up (Vulkan and GL backends), the
//! classification of each adapter as hardware or software, and the ranking
//! `auto` uses: a hardware adapter (Vulkan, then GL), then a software adapter
//! (Mesa lavapipe through Vulkan, then llvmpipe through GL). Takes nothing but
//! the machine; gives out [`AdapterSummary`] lists for `star doctor` and the
//! chosen `wgpu::Adapter` for [`super::GpuRenderer`].

use std::fmt;

/// Which class of wgpu adapter a renderer asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdapterPreference {
    /// A hardware GPU (integrated or discrete), Vulkan before GL.
    Hardware,
    /// A software rasterizer behind a graphics API (lavapipe, llvmpipe),
    /// Vulkan before GL.
    Software,
}

impl AdapterPreference {
    /// The adapter class this preference asks for.
    pub fn class(self) -> AdapterClass {
        match self {
            Self::Hardware => AdapterClass::Hardware,
            Self::Software => AdapterClass::Software,
        }
    }
}

impl fmt::Display for AdapterPreference {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Hardware => "hardware",
            Self::Software => "software",
        })
    }
}

/// Whether an adapter is a real GPU or a software rasterizer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AdapterClass {
    /// A GPU: integrated, discrete, virtual, or of unknown type.
    Hardware,
    /// A CPU implementation of the API (lavapipe, llvmpipe, SwiftShader).
    Software,
}

/// One adapter as `star doctor` shows it.
#[derive(Debug, Clone, PartialEq)]
pub struct AdapterSummary {
    /// The adapter's name, e.g. `llvmpipe (LLVM 15.0.7, 256 bits)`.
    pub name: String,
    /// The graphics API.
    pub backend: wgpu::Backend,
    /// The device type the driver reports.
    pub device_type: wgpu::DeviceType,
    /// Driver name and version, as reported.
    pub driver: String,
    /// Hardware or software.
    pub class: AdapterClass,
    /// Position in the order `auto` tries adapters of this class (0 first).
    pub rank: usize,
}

impl fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ({:?}, {:?}, driver {})",
            self.name, self.backend, self.device_type, self.driver
        )
    }
}

/// The backends the renderer uses: Vulkan first, GL second.
pub const BACKENDS: wgpu::Backends = wgpu::Backends::VULKAN.union(wgpu::Backends::GL);

/// Names of software implementations that may report another device type.
const SOFTWARE_NAMES: [&str; 5] = [
    "llvmpipe",
    "lavapipe",
    "softpipe",
    "swiftshader",
    "software",
];

/// The backends in the order the renderer tries them.
pub const BACKEND_ORDER: [wgpu::Backends; 2] = [wgpu::Backends::VULKAN, wgpu::Backends::GL];

/// A wgpu instance over `backends`. Debug and validation layers stay off
/// unless `WGPU_DEBUG`/`WGPU_VALIDATION` ask for them.
pub fn new_instance(backends: wgpu::Backends) -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = backends;
    desc.flags = wgpu::InstanceFlags::empty().with_env();
    wgpu::Instance::new(desc)
}

/// Classifies an adapter from what its driver reports.
pub fn classify(info: &wgpu::AdapterInfo) -> AdapterClass {
    classify_parts(&info.name, &info.driver, info.device_type)
}

fn classify_parts(name: &str, driver: &str, device_type: wgpu::DeviceType) -> AdapterClass {
    let name = name.to_lowercase();
    let driver = driver.to_lowercase();
    let named_software = SOFTWARE_NAMES
        .iter()
        .any(|s| name.contains(s) || driver.contains(s));
    if device_type == wgpu::DeviceType::Cpu || named_software {
        AdapterClass::Software
    } else {
        AdapterClass::Hardware
    }
}

/// Sort key within a class: Vulkan before GL, then integrated (the target
/// platform's Intel iGPU) before discrete, virtual and unknown.
fn order_key(backend: wgpu::Backend, device_type: wgpu::DeviceType) -> (u8, u8) {
    let backend = match backend {
        wgpu::Backend::Vulkan => 0,
        wgpu::Backend::Gl => 1,
        _ => 2,
    };
    let device = match device_type {
        wgpu::DeviceType::IntegratedGpu => 0,
        wgpu::DeviceType::DiscreteGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    (backend, device)
}

/// Every adapter `instance` sees, each class in the order it would be tried.
pub fn enumerate(instance: &wgpu::Instance) -> Vec<wgpu::Adapter> {
    let mut adapters = pollster::block_on(instance.enumerate_adapters(BACKENDS));
    adapters.sort_by_key(|a| {
        let info = a.get_info();
        order_key(info.backend, info.device_type)
    });
    adapters
}

/// Lists every adapter wgpu sees (Vulkan and GL), with its class and its
/// rank within the class; the hardware adapter of rank 0 is what
/// `renderer = "auto"` chooses (without one, auto uses the CPU rasterizer).
pub fn list_adapters() -> Vec<AdapterSummary> {
    let instance = new_instance(BACKENDS);
    let mut ranks = [0usize; 2];
    enumerate(&instance)
        .iter()
        .map(|a| {
            let info = a.get_info();
            let class = classify(&info);
            let slot = &mut ranks[usize::from(class == AdapterClass::Software)];
            let rank = *slot;
            *slot += 1;
            AdapterSummary {
                driver: format!("{} {}", info.driver, info.driver_info)
                    .trim()
                    .to_string(),
                name: info.name,
                backend: info.backend,
                device_type: info.device_type,
                class,
                rank,
            }
        })
        .collect()
}

/// The adapter `auto` would choose among `adapters` (as [`list_adapters`]
/// returns them): the best hardware one; `None` means the CPU rasterizer,
/// which auto prefers to a software adapter (see [`crate::render::select`]).
pub fn auto_choice(adapters: &[AdapterSummary]) -> Option<&AdapterSummary> {
    adapters
        .iter()
        .find(|a| a.class == AdapterClass::Hardware && a.rank == 0)
}

/// True when Mesa's lavapipe Vulkan driver is installed, so a software
/// adapter must exist (tests use this to refuse skipping the wgpu path).
pub fn lavapipe_installed() -> bool {
    ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d"]
        .iter()
        .any(|dir| {
            std::fs::read_dir(dir).is_ok_and(|entries| {
                entries.flatten().any(|e| {
                    let name = e.file_name();
                    let name = name.to_string_lossy();
                    name.starts_with("lvp_icd") && name.ends_with(".json")
                })
            })
        })
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn classifies_software_by_type_and_name() {
        use wgpu::DeviceType;
        let lvp = classify_parts("llvmpipe (LLVM 15)", "llvmpipe", DeviceType::Cpu);
        assert_eq!(lvp, AdapterClass::Software);
        let gl_sw = classify_parts("llvmpipe (LLVM 15)", "", DeviceType::Other);
        assert_eq!(gl_sw, AdapterClass::Software);
        let igpu = classify_parts("Intel(R) UHD 620", "Intel", DeviceType::IntegratedGpu);
        assert_eq!(igpu, AdapterClass::Hardware);
        let unknown = classify_parts("Some GPU", "", DeviceType::Other);
        assert_eq!(unknown, AdapterClass::Hardware);
    }

    #[test]
    fn vulkan_before_gl_and_integrated_first() {
        use wgpu::{Backend, DeviceType};
        let gl = order_key(Backend::Gl, DeviceType::IntegratedGpu);
        let vk = order_key(Backend::Vulkan, DeviceType::DiscreteGpu);
        let vk_i = order_key(Backend::Vulkan, DeviceType::IntegratedGpu);
        assert!(vk < gl && vk_i < vk);
    }

    #[test]
    fn auto_prefers_hardware_then_software() {
        let sw = AdapterSummary {
            name: "llvmpipe".into(),
            backend: wgpu::Backend::Vulkan,
            device_type: wgpu::DeviceType::Cpu,
            driver: String::new(),
            class: AdapterClass::Software,
            rank: 0,
        };
        let hw = AdapterSummary {
            name: "Intel".into(),
            class: AdapterClass::Hardware,
            device_type: wgpu::DeviceType::IntegratedGpu,
            ..sw.clone()
        };
        assert_eq!(auto_choice(std::slice::from_ref(&sw)), None);
        assert_eq!(auto_choice(&[sw.clone(), hw.clone()]), Some(&hw));
        assert_eq!(auto_choice(&[]), None);
    }
}

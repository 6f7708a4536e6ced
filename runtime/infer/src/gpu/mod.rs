//! The `wgpu` backend: the lowered network run as generated WGSL compute
//! kernels (tiled conv with fused epilogue, 2×2 max pool, 2×2 transposed
//! conv; concatenation costs nothing, producers write into channel ranges
//! of the concat's buffer). The weight buffer is built once per network;
//! each kernel variant's pipeline (the conv's tile depends on the layer's
//! size) when a frame size first needs it, then kept; buffers and bind
//! groups once per frame size; a frame only uploads, records the
//! dispatches and reads back.
//!
//! A frame whose largest activation does not fit one storage binding of
//! the adapter (lavapipe and wgpu's defaults bind 128 MiB; the shipped
//! network's largest activation is 253 MiB in f32 at 1920×1080) runs in
//! horizontal bands, each with a halo of the network's receptive radius
//! and aligned to its multiple, so every band's kept rows equal the whole
//! frame's result exactly.
//!
//! f16 mode stores weights and intermediate activations as f16 and
//! accumulates in f32; the frame in and the display out stay f32.

mod banding;
mod choose;
pub mod codegen;
#[cfg(test)]
mod coop_model;
mod fused;
mod pack;
pub mod params;
mod plan;
mod profile;
mod resident;
mod tuner;
mod tuner_fused;
pub mod tuning;

pub use choose::{ConvSupport, cooperative_against_tiled};
pub use fused::LayerFused;
pub use resident::DeviceDcnn;
pub use tuner::{TuneKinds, TuneResult};

use std::collections::HashMap;
use std::sync::Arc;

use codegen::{Dtype, KernelKey};
use nedrt_gpu::PassTimer;
use plan::SizedPlan;
use wgpu::util::DeviceExt;

use super::network::{Layer, Network, ValueId};
use super::{Backend, BackendOptions, InferenceError, Precision};
use nedrt_core::Image;
use nedrt_core::preprocess::HostTraffic;

fn err(reason: impl std::fmt::Display) -> InferenceError {
    InferenceError::Backend {
        backend: "wgpu",
        reason: reason.to_string(),
    }
}

/// One kernel variant's compute pipeline.
fn build_pipeline(
    device: &wgpu::Device,
    layout: &wgpu::PipelineLayout,
    key: &KernelKey,
) -> wgpu::ComputePipeline {
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(&key.label()),
        source: wgpu::ShaderSource::Wgsl(key.wgsl().into()),
    });
    device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(&key.label()),
        layout: Some(layout),
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    })
}

/// Opens the default adapter's device for `precision` (f16 needs the
/// adapter's shader-f16).
pub fn open_device(
    settings: &nedrt_gpu::GpuSettings,
    precision: Precision,
) -> Result<(wgpu::Adapter, wgpu::Device, wgpu::Queue), InferenceError> {
    Ok(nedrt_gpu::open_device(
        settings,
        precision == Precision::F16,
    )?)
}

/// The network on a wgpu device.
#[derive(Debug)]
pub struct GpuBackend {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter_name: String,
    network: Network,
    precision: Precision,
    layout: wgpu::BindGroupLayout,
    pipeline_layout: wgpu::PipelineLayout,
    /// Every kernel variant built so far; a frame size whose layers want
    /// other conv tiles adds theirs when its plan is made.
    pipelines: HashMap<KernelKey, wgpu::ComputePipeline>,
    /// Per layer: its kernel, conv tiles at `ConvTile::LARGE` (None for
    /// Concat). `SizedPlan` picks each conv layer's tile for its size.
    layer_keys: Vec<Option<KernelKey>>,
    weights: wgpu::Buffer,
    /// Per layer: (weight offset, bias offset) in elements.
    weight_offsets: Vec<(usize, usize)>,
    /// Concat inputs placed inside their concat: value → (concat value, channel offset).
    alias: HashMap<ValueId, (ValueId, usize)>,
    dummy: wgpu::Buffer,
    plan: Option<SizedPlan>,
    /// Start/end timestamps of the network's pass, where the device has them.
    timer: Option<PassTimer>,
    last_gpu_ns: Option<u64>,
    /// What the last frame moved between host and device (every band).
    last_traffic: HostTraffic,
    /// The most bytes one activation buffer may have (the adapter's storage
    /// binding and buffer limits, or a smaller one set for tests).
    binding_cap: u64,
    /// Rows a band carries above and below the rows it keeps.
    halo: usize,
    /// The frame size whose banding was last reported.
    banded_size: Option<(usize, usize)>,
    /// Copies between a frame on the device and the network's tensors.
    window: resident::WindowKernel,
    /// Those copies for one frame size and pair of buffers.
    resident: Option<resident::ResidentPlan>,
    /// Each convolution's kernel and why (`conv_paths`).
    conv_paths: Vec<String>,
    /// Conv tiles tuned for this adapter (`nedrt bench tune`), if any.
    tuning: Option<Arc<tuning::TuningTable>>,
    /// Tiles the tuner forces on layers, over the table and heuristics.
    forced_tiles: HashMap<usize, codegen::ConvTile>,
    /// The same for the cooperative-matrix layers.
    forced_coop: HashMap<usize, codegen::coop::CoopTile>,
    /// Levels the tuner fuses (first layer → tile), over the table.
    forced_fused: HashMap<usize, codegen::fused::FusedTile>,
    /// A tile whose output the tests corrupt where it is forced (a kernel
    /// bug for the tuner to pass over).
    #[cfg(test)]
    pub(crate) fault_tile: Option<codegen::ConvTile>,
}

impl GpuBackend {
    /// Opens the default adapter and prepares `network` on it.
    pub fn new_default(
        network: &Network,
        options: &BackendOptions,
    ) -> Result<Self, InferenceError> {
        let (adapter, device, queue) = open_device(&options.gpu, options.precision)?;
        let info = adapter.get_info();
        let name = format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type);
        Self::with_options(&device, &queue, name, network, options)
    }

    /// Prepares `network` on a given device at `options`' precision, conv
    /// path and f16 math.
    pub fn with_options(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: String,
        network: &Network,
        options: &BackendOptions,
    ) -> Result<Self, InferenceError> {
        let support = ConvSupport::of_options(device, options);
        let tuning = match &options.tuning_dir {
            Some(dir) => tuning::table_for(dir, &device.adapter_info())?,
            None => None,
        };
        Ok(Self::new_with(
            device,
            queue,
            adapter_name,
            network,
            options.precision,
            support,
        )?
        .with_tuning(tuning))
    }

    /// Prepares `network` on a given device, each convolution on the
    /// kernels the device offers (`ConvPath::Auto`).
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: String,
        network: &Network,
        precision: Precision,
    ) -> Result<Self, InferenceError> {
        let support = ConvSupport::of_device(device, crate::ConvPath::Auto);
        Self::new_with(device, queue, adapter_name, network, precision, support)
    }

    /// Prepares `network` on a given device: its kernels' keys and weights
    /// (the pipelines are built by the first frame size that needs them),
    /// each convolution on the kernels `support` allows.
    pub fn new_with(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        adapter_name: String,
        network: &Network,
        precision: Precision,
        support: ConvSupport,
    ) -> Result<Self, InferenceError> {
        if precision == Precision::F16 && !device.features().contains(wgpu::Features::SHADER_F16) {
            return Err(err("the device was opened without shader-f16"));
        }
        // wgpu reports errors through a handler that panics by default.
        device.on_uncaptured_error(std::sync::Arc::new(|e| {
            tracing::error!("wgpu: {e}");
        }));
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let t = storage_dtype(precision);
        let dtype = |v: ValueId| {
            if v == 0 || v == network.output {
                Dtype::F32
            } else {
                t
            }
        };
        let alias = concat_aliases(network);
        for layer in &network.layers {
            if let Layer::Concat { inputs, output } = layer {
                let mut ch = 0;
                for &i in inputs {
                    if alias.get(&i) != Some(&(*output, ch)) {
                        return Err(err(format!(
                            "a concat input (value {i}) is the frame, the output, or feeds \
                             another concat; the GPU backend writes concat inputs in place \
                             and does not support that"
                        )));
                    }
                    ch += network.values[i].channels;
                }
            }
        }
        let root = |mut v: ValueId| {
            while let Some(&(c, _)) = alias.get(&v) {
                v = c;
            }
            v
        };

        let storage = |read_only: bool| wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        };
        let entry = |binding: u32, ty| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty,
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("dcnn layer"),
            entries: &[
                entry(
                    0,
                    wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: true },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                ),
                entry(1, storage(true)),
                entry(2, storage(true)),
                entry(3, storage(false)),
                entry(4, storage(true)),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("dcnn layer"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });

        let mut layer_keys = Vec::new();
        let mut weights: Vec<f32> = Vec::new();
        let mut weight_offsets = Vec::new();
        let mut conv_paths = Vec::new();
        for (li, layer) in network.layers.iter().enumerate() {
            let Some(k) = choose::layer_kernel(layer, network, t, &support)? else {
                layer_keys.push(None);
                weight_offsets.push((0, 0));
                continue;
            };
            if let Some(path) = k.path {
                tracing::info!("D-CNN layer {li}, {path}");
                conv_paths.push(format!("layer {li}, {path}"));
            }
            let (kind, input, residual) = (k.kind, k.input, k.residual);
            // Cooperative loads want 16-byte aligned matrices: every
            // layer's weights start at a multiple of 16 elements.
            weights.resize(weights.len().next_multiple_of(16), 0.0);
            weight_offsets.push((weights.len(), weights.len() + k.weights.len()));
            weights.extend_from_slice(&k.weights);
            weights.extend_from_slice(&k.bias);
            let key = KernelKey {
                kind,
                src: dtype(root(input)),
                dst: dtype(root(layer.output())),
                residual: residual.map_or(Dtype::F32, |r| dtype(root(r))),
                weights: t,
                arith: if support.f16_arithmetic {
                    t
                } else {
                    Dtype::F32
                },
            };
            layer_keys.push(Some(key));
        }
        if weights.len() > u32::MAX as usize {
            return Err(err("more than 2^32 weights"));
        }
        let weight_bytes: Vec<u8> = match t {
            Dtype::F32 => bytemuck::cast_slice(&weights).to_vec(),
            Dtype::F16 => {
                let h: Vec<half::f16> = weights.iter().map(|&v| half::f16::from_f32(v)).collect();
                bytemuck::cast_slice(&h).to_vec()
            }
        };
        let weights = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("dcnn weights"),
            contents: &pad4(weight_bytes),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let dummy = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("unused binding"),
            size: 4,
            usage: wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(err(format!("building the kernels: {e}")));
        }
        let limits = device.limits();
        let m = network.multiple.max(1);
        Ok(Self {
            device: device.clone(),
            queue: queue.clone(),
            adapter_name,
            network: network.clone(),
            precision,
            layout,
            pipeline_layout,
            pipelines: HashMap::new(),
            layer_keys,
            weights,
            weight_offsets,
            alias,
            dummy,
            plan: None,
            timer: PassTimer::new(device, queue, 1),
            last_gpu_ns: None,
            last_traffic: HostTraffic::default(),
            binding_cap: limits
                .max_storage_buffer_binding_size
                .min(limits.max_buffer_size),
            halo: network.receptive_radius().next_multiple_of(m),
            banded_size: None,
            window: resident::WindowKernel::new(device),
            resident: None,
            conv_paths,
            tuning: None,
            forced_tiles: HashMap::new(),
            forced_coop: HashMap::new(),
            forced_fused: HashMap::new(),
            #[cfg(test)]
            fault_tile: None,
        })
    }

    /// Uses `table`'s conv tiles where it has the layer's shape.
    pub fn with_tuning(mut self, table: Option<Arc<tuning::TuningTable>>) -> Self {
        self.set_tuning(table);
        self
    }

    /// [`Self::with_tuning`] in place (None: the heuristics' tiles).
    pub fn set_tuning(&mut self, table: Option<Arc<tuning::TuningTable>>) {
        self.tuning = table;
        self.plan = None;
        self.resident = None;
    }

    /// The tuning table in use, if any.
    pub fn tuning(&self) -> Option<&tuning::TuningTable> {
        self.tuning.as_deref()
    }

    /// Forces `tiles` (layer index → tile) over the table and the
    /// heuristics, for the tuner; an empty map lifts them.
    pub fn force_conv_tiles(&mut self, tiles: HashMap<usize, codegen::ConvTile>) {
        if tiles != self.forced_tiles {
            self.forced_tiles = tiles;
            self.plan = None;
            self.resident = None;
        }
    }

    /// [`Self::force_conv_tiles`] for the cooperative-matrix layers.
    pub fn force_coop_tiles(&mut self, tiles: HashMap<usize, codegen::coop::CoopTile>) {
        if tiles != self.forced_coop {
            self.forced_coop = tiles;
            self.plan = None;
            self.resident = None;
        }
    }

    /// Caps each activation buffer at `bytes` (at most the adapter's own
    /// limit): frames whose activations are larger run in bands. For tests
    /// of the banding on adapters with large limits.
    pub fn with_binding_limit(mut self, bytes: u64) -> Self {
        self.binding_cap = self.binding_cap.min(bytes);
        self.plan = None;
        self.resident = None;
        self
    }

    /// Each convolution's kernel, tiled or cooperative matrix, and why:
    /// one line a layer, in the network's order.
    pub fn conv_paths(&self) -> &[String] {
        &self.conv_paths
    }

    fn dtype(&self, root: ValueId) -> Dtype {
        if root == 0 || root == self.network.output {
            Dtype::F32
        } else {
            storage_dtype(self.precision)
        }
    }

    /// Makes (or keeps) the plan for `width`×`height` windows.
    fn ensure_plan(&mut self, width: usize, height: usize) -> Result<(), InferenceError> {
        if self
            .plan
            .as_ref()
            .is_none_or(|p| (p.width, p.height) != (width, height))
        {
            // The device frame's copies bind the old plan's buffers.
            self.resident = None;
            self.plan = None;
            self.plan = Some(self.prepare(width, height)?);
        }
        Ok(())
    }
}

/// How weights and intermediate activations are stored at `precision`.
fn storage_dtype(precision: Precision) -> Dtype {
    match precision {
        Precision::F32 => Dtype::F32,
        Precision::F16 => Dtype::F16,
    }
}

fn pad4(mut bytes: Vec<u8>) -> Vec<u8> {
    bytes.resize(bytes.len().next_multiple_of(4).max(4), 0);
    bytes
}

/// Places each concat input inside its concat's buffer where it can be:
/// not the frame, not the output, and not already placed in another concat.
fn concat_aliases(net: &Network) -> HashMap<ValueId, (ValueId, usize)> {
    let mut alias = HashMap::new();
    for layer in &net.layers {
        if let Layer::Concat { inputs, output } = layer {
            let mut ch = 0;
            for &i in inputs {
                if i != 0 && i != net.output && !alias.contains_key(&i) {
                    alias.insert(i, (*output, ch));
                }
                ch += net.values[i].channels;
            }
        }
    }
    alias
}

impl Backend for GpuBackend {
    fn describe(&self) -> String {
        let p = match self.precision {
            Precision::F32 => "f32",
            Precision::F16 => "f16",
        };
        let coop = self
            .conv_paths
            .iter()
            .filter(|l| l.contains(": cooperative matrix"))
            .count();
        let tiled = self.conv_paths.len() - coop;
        let paths = match (coop, tiled) {
            (0, _) => "tiled convolutions".to_string(),
            (_, 0) => "convolutions on cooperative matrices".to_string(),
            _ => format!("{coop} convolutions on cooperative matrices, {tiled} tiled"),
        };
        format!("wgpu {p} on {}, {paths}", self.adapter_name)
    }

    fn last_gpu_ns(&self) -> Option<u64> {
        self.last_gpu_ns
    }

    fn conv_paths(&self) -> Vec<String> {
        self.conv_paths.clone()
    }

    fn last_traffic(&self) -> HostTraffic {
        self.last_traffic
    }

    fn layer_timings(&mut self, frame: &Image) -> Result<Vec<crate::LayerTiming>, InferenceError> {
        GpuBackend::layer_timings(self, frame)
    }

    fn run(&mut self, frame: &Image) -> Result<Image, InferenceError> {
        let data = self.run_tensor(frame.data(), frame.width, frame.height)?;
        Ok(Image::rgb(frame.width, frame.height, data))
    }
}

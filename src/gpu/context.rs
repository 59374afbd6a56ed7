//! [`GpuContext`]: one adapter, device and queue, with the pipelines and buffers of the runs
//! made on it; [`PassTimer`]: the passes of one run, timed.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use super::adapter::{choose, AdapterDescription, Device};
use crate::timing::{Clock, Timings};
use crate::{Error, Result};

/// Buffers the pool keeps for reuse at most (a frame of `multilayer` holds about 40); the
/// oldest is dropped beyond.
const POOL_BUFFERS: usize = 64;

/// Bytes the pool keeps for reuse at most; the oldest buffers are dropped beyond (a frame of
/// another size does not keep the last one's buffers alive).
const POOL_BYTES: u64 = 512 << 20;

/// Textures the pool keeps for reuse at most ([`GpuContext::texture`]); the oldest is dropped
/// beyond, or beyond [`POOL_BYTES`] of them.
const POOL_TEXTURES: usize = 16;

/// Values the cache keeps at most ([`GpuContext::cached`]); the oldest is dropped beyond.
const CACHE_ENTRIES: usize = 8;

/// A value of the cache, by key.
type CacheEntry = (String, Arc<dyn std::any::Any + Send + Sync>);

/// The wgpu instance of the backends defocus uses (Vulkan, Metal, DX12; `WGPU_BACKEND`
/// narrows them), without Vulkan's validation layers unless `WGPU_VALIDATION` asks.
pub(crate) fn new_instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::PRIMARY.with_env();
    desc.flags = wgpu::InstanceFlags::empty().with_env();
    wgpu::Instance::new(desc)
}

/// The adapters of `instance`, in wgpu's order.
pub(crate) fn enumerate(instance: &wgpu::Instance) -> Vec<wgpu::Adapter> {
    pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
}

/// A GPU device and its queue, with the compiled pipelines and pooled buffers of the runs made
/// on it. Made once per job ([`GpuContext::open`]) and passed to every run: a sequence or a
/// batch reuses its pipelines and buffers. Shared between threads (`Sync`).
pub struct GpuContext {
    device: wgpu::Device,
    queue: wgpu::Queue,
    description: AdapterDescription,
    /// Whether passes are timed by timestamp queries.
    timestamps: bool,
    /// Compiled shader modules by shader name.
    modules: Mutex<HashMap<&'static str, wgpu::ShaderModule>>,
    /// Compiled pipelines by pass name.
    pipelines: Mutex<HashMap<&'static str, wgpu::ComputePipeline>>,
    /// Buffers given back after a run, for the next one of the same size and use.
    pool: Mutex<Vec<wgpu::Buffer>>,
    /// Textures given back after a run (render targets), for the next one of the same size,
    /// format and use.
    texture_pool: Mutex<Vec<wgpu::Texture>>,
    /// Per-frame constants uploaded once and reused by the frames that have the same (a
    /// method's tap tables), newest last.
    cache: Mutex<Vec<CacheEntry>>,
    /// Errors wgpu reported outside an error scope (validation, out of memory, device lost),
    /// returned by the next [`GpuContext::check`].
    errors: Arc<Mutex<Vec<String>>>,
    /// Why the device was lost, once it was: every later run is refused with it.
    lost: Arc<Mutex<Option<String>>>,
    /// Opened for `--device auto` (see [`GpuContext::chosen_by_auto`]).
    auto: bool,
    /// Buffers and textures made on the device (the pools' misses), for
    /// [`GpuContext::allocations`].
    made: std::sync::atomic::AtomicU64,
    // Kept so that the adapter outlives the device on every backend.
    _adapter: wgpu::Adapter,
    _instance: wgpu::Instance,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &self.description.label())
            .field("timestamps", &self.timestamps)
            .finish_non_exhaustive()
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding the lock leaves a map that is still whole.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl GpuContext {
    /// The context of `device` on this machine's adapters ([`super::choose`]): `None` for the
    /// CPU (`cpu`, or `auto` without a hardware adapter; `auto` does not load a Vulkan driver
    /// where no GPU device node exists, [`super::adapter::hardware_may_exist`]).
    pub fn open(device: Device) -> Result<Option<Self>> {
        match device {
            Device::Cpu => return Ok(None),
            Device::Auto if !super::adapter::hardware_may_exist() => return Ok(None),
            _ => {}
        }
        let instance = new_instance();
        let mut adapters = enumerate(&instance);
        let descriptions: Vec<AdapterDescription> =
            adapters.iter().map(AdapterDescription::of).collect();
        match choose(device, &descriptions)? {
            None => Ok(None),
            Some(i) => {
                let adapter = adapters.swap_remove(i);
                let mut ctx = Self::on_adapter(instance, adapter)?;
                ctx.auto = device == Device::Auto;
                Ok(Some(ctx))
            }
        }
    }

    /// A context on `adapter`: its device with timestamp queries where it has them, and the
    /// adapter's own limits (not WebGPU's defaults), so a frame is refused only where the
    /// hardware would refuse it.
    fn on_adapter(instance: wgpu::Instance, adapter: wgpu::Adapter) -> Result<Self> {
        let description = AdapterDescription::of(&adapter);
        let timestamps = description.timestamp_query;
        let required_features = if timestamps {
            wgpu::Features::TIMESTAMP_QUERY
        } else {
            wgpu::Features::empty()
        };
        let desc = wgpu::DeviceDescriptor {
            label: Some("defocus"),
            required_features,
            required_limits: adapter.limits(),
            ..Default::default()
        };
        let (device, queue) = pollster::block_on(adapter.request_device(&desc)).map_err(|e| {
            Error::Gpu(format!(
                "could not open a device on {}: {e}",
                description.label()
            ))
        })?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&errors);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            lock(&sink).push(e.to_string());
        }));
        let lost = Arc::new(Mutex::new(None));
        let sink = Arc::clone(&lost);
        device.set_device_lost_callback(move |reason, message| {
            let why = if message.trim().is_empty() {
                format!("{reason:?}")
            } else {
                format!("{reason:?}: {message}")
            };
            *lock(&sink) = Some(why);
        });
        Ok(Self {
            device,
            queue,
            description,
            timestamps,
            modules: Mutex::new(HashMap::new()),
            pipelines: Mutex::new(HashMap::new()),
            pool: Mutex::new(Vec::new()),
            texture_pool: Mutex::new(Vec::new()),
            cache: Mutex::new(Vec::new()),
            errors,
            lost,
            auto: false,
            made: std::sync::atomic::AtomicU64::new(0),
            _adapter: adapter,
            _instance: instance,
        })
    }

    /// True when the context was opened for `--device auto`: a run whose settings the GPU
    /// passes do not cover then goes to the CPU instead of being refused
    /// ([`crate::methods::registry::runs_on_gpu`]).
    pub fn chosen_by_auto(&self) -> bool {
        self.auto
    }

    /// The adapter the context runs on.
    pub fn description(&self) -> &AdapterDescription {
        &self.description
    }

    /// Whether passes are timed by timestamp queries (GPU time) rather than by the wall time
    /// around their submit and wait.
    pub fn has_timestamps(&self) -> bool {
        self.timestamps
    }

    /// The wgpu device.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The wgpu queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The error wgpu reported since the last check (validation, out of memory, a lost
    /// device), as [`Error::Gpu`] naming the adapter; `Ok` when there was none.
    pub fn check(&self) -> Result<()> {
        let errors: Vec<String> = std::mem::take(&mut *lock(&self.errors));
        if let Some(why) = lock(&self.lost).as_ref() {
            return Err(Error::Gpu(format!(
                "{}: the device was lost ({why}; a driver reset, a hung GPU or too little \
                 memory): nothing more runs on it, run again",
                self.description.label()
            )));
        }
        if errors.is_empty() {
            Ok(())
        } else {
            Err(Error::Gpu(format!(
                "{}: {}",
                self.description.label(),
                errors.join("; ")
            )))
        }
    }

    /// The compute pipeline of entry point `pass` (a pass name such as `gaussian/coc`: the
    /// entry point is the part after the last `/`) of the WGSL shader `shader` named
    /// `shader_name`, compiled on first use and cached. A shader that naga refuses is an
    /// [`Error::Gpu`] with naga's message.
    pub fn pipeline(
        &self,
        shader_name: &'static str,
        shader: &'static str,
        pass: &'static str,
    ) -> Result<wgpu::ComputePipeline> {
        if let Some(p) = lock(&self.pipelines).get(pass) {
            return Ok(p.clone());
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = lock(&self.modules)
            .entry(shader_name)
            .or_insert_with(|| {
                self.device
                    .create_shader_module(wgpu::ShaderModuleDescriptor {
                        label: Some(shader_name),
                        source: wgpu::ShaderSource::Wgsl(shader.into()),
                    })
            })
            .clone();
        let entry = pass.rsplit('/').next().unwrap_or(pass);
        let pipeline = self
            .device
            .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(pass),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            });
        if let Some(e) = pollster::block_on(scope.pop()) {
            lock(&self.modules).remove(shader_name);
            return Err(Error::Gpu(format!(
                "the pipeline {pass} of {shader_name} did not build: {e}"
            )));
        }
        lock(&self.pipelines).insert(pass, pipeline.clone());
        Ok(pipeline)
    }

    /// Checks a run's GPU memory before anything is allocated: its largest buffer,
    /// `largest_bytes`, against the adapter's limits ([`GpuContext::check_storage`]), and all
    /// it allocates, `total_bytes` (the read-back copy included), against the memory budget
    /// (`--memory-budget`), naming `what`.
    pub fn plan(&self, what: &str, largest_bytes: u64, total_bytes: u64) -> Result<()> {
        self.check_storage(what, largest_bytes)?;
        crate::budget::check(
            total_bytes,
            &format!("{what} on {}", self.description.label()),
            "the resolution",
        )
    }

    /// Checks that a storage buffer of `bytes` fits the adapter's limits, naming `what` it
    /// holds and the limit it passes, before anything is allocated.
    pub fn check_storage(&self, what: &str, bytes: u64) -> Result<()> {
        let l = &self.description.limits;
        for (limit, name) in [
            (
                l.max_storage_buffer_binding_size,
                "max storage buffer binding size",
            ),
            (l.max_buffer_size, "max buffer size"),
        ] {
            if bytes > limit {
                return Err(Error::Gpu(format!(
                    "{what} needs a buffer of {bytes} bytes; {} allows {limit} ({name})",
                    self.description.label()
                )));
            }
        }
        Ok(())
    }

    /// A buffer of `size` bytes and `usage`, from the pool when one was given back, else new.
    /// Its contents are undefined.
    pub fn buffer(
        &self,
        label: &'static str,
        size: u64,
        usage: wgpu::BufferUsages,
    ) -> wgpu::Buffer {
        let size = size.max(4).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
        {
            let mut pool = lock(&self.pool);
            if let Some(i) = pool
                .iter()
                .position(|b| b.size() == size && b.usage() == usage)
            {
                return pool.swap_remove(i);
            }
        }
        self.made.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        })
    }

    /// How many buffers and textures the context has made on the device so far: those its
    /// pools could not give back. The frames of a sequence after its first ones make none.
    pub fn allocations(&self) -> u64 {
        self.made.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Gives buffers back to the pool for the next run (the oldest are dropped beyond 64
    /// buffers or 512 MiB).
    pub fn recycle(&self, buffers: impl IntoIterator<Item = wgpu::Buffer>) {
        let mut pool = lock(&self.pool);
        pool.extend(buffers);
        let excess = pool.len().saturating_sub(POOL_BUFFERS);
        pool.drain(..excess);
        let mut bytes: u64 = pool.iter().map(|b| b.size()).sum();
        while bytes > POOL_BYTES && !pool.is_empty() {
            bytes -= pool.remove(0).size();
        }
    }

    /// A 2D texture of `width` x `height` texels of `format` and `usage`, from the pool when
    /// one was given back, else new. Its contents are undefined.
    pub fn texture(
        &self,
        label: &'static str,
        (width, height): (u32, u32),
        format: wgpu::TextureFormat,
        usage: wgpu::TextureUsages,
    ) -> wgpu::Texture {
        {
            let mut pool = lock(&self.texture_pool);
            if let Some(i) = pool.iter().position(|t| {
                (t.width(), t.height(), t.format(), t.usage()) == (width, height, format, usage)
            }) {
                return pool.swap_remove(i);
            }
        }
        self.made.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    }

    /// Gives textures back to the pool for the next run (the oldest are dropped beyond 16
    /// textures or 512 MiB).
    pub fn recycle_textures(&self, textures: impl IntoIterator<Item = wgpu::Texture>) {
        let bytes_of = |t: &wgpu::Texture| {
            let texel = t.format().block_copy_size(None).unwrap_or(16);
            u64::from(t.width()) * u64::from(t.height()) * u64::from(texel)
        };
        let mut pool = lock(&self.texture_pool);
        pool.extend(textures);
        let excess = pool.len().saturating_sub(POOL_TEXTURES);
        pool.drain(..excess);
        let mut bytes: u64 = pool.iter().map(bytes_of).sum();
        while bytes > POOL_BYTES && !pool.is_empty() {
            bytes -= bytes_of(&pool.remove(0));
        }
    }

    /// A storage buffer holding `data`, checked against the limits first.
    pub fn upload(&self, label: &'static str, data: &[u8]) -> Result<wgpu::Buffer> {
        self.check_storage(label, data.len() as u64)?;
        let usage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        let buffer = self.buffer(label, data.len() as u64, usage);
        if !data.is_empty() {
            self.queue.write_buffer(&buffer, 0, data);
        }
        Ok(buffer)
    }

    /// A storage buffer of `bytes` bytes whose contents are undefined until a pass writes
    /// them, checked against the limits first.
    pub fn storage(&self, label: &'static str, bytes: u64) -> Result<wgpu::Buffer> {
        self.check_storage(label, bytes)?;
        let usage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        Ok(self.buffer(label, bytes, usage))
    }

    /// A uniform buffer holding `data`.
    pub fn uniform(&self, label: &'static str, data: &[u8]) -> wgpu::Buffer {
        let usage = wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST;
        let buffer = self.buffer(label, data.len() as u64, usage);
        self.queue.write_buffer(&buffer, 0, data);
        buffer
    }

    /// The value cached under `key`, or `make`'s, cached for the next frames (a sequence, a
    /// batch, a benchmark's repeats) that ask for the same key. `key` must say everything the
    /// value depends on; a value of another type under the same key is replaced.
    pub fn cached<T: std::any::Any + Send + Sync>(
        &self,
        key: &str,
        make: impl FnOnce() -> Result<T>,
    ) -> Result<Arc<T>> {
        {
            let cache = lock(&self.cache);
            if let Some((_, v)) = cache.iter().find(|(k, _)| k == key) {
                if let Ok(v) = Arc::clone(v).downcast::<T>() {
                    return Ok(v);
                }
            }
        }
        let value = Arc::new(make()?);
        let mut cache = lock(&self.cache);
        cache.retain(|(k, _)| k != key);
        cache.push((key.to_string(), Arc::clone(&value) as _));
        let excess = cache.len().saturating_sub(CACHE_ENTRIES);
        cache.drain(..excess);
        Ok(value)
    }

    /// The compute pipelines of `passes` (each an entry point of `shader`, see
    /// [`GpuContext::pipeline`]), in their order.
    pub fn pipelines(
        &self,
        shader_name: &'static str,
        shader: &'static str,
        passes: &[&'static str],
    ) -> Result<Vec<wgpu::ComputePipeline>> {
        passes
            .iter()
            .map(|pass| self.pipeline(shader_name, shader, pass))
            .collect()
    }

    /// A frame's result read back with its status word in one submit: the `width` x `height`
    /// RGBA image of `out`, or `Err` with the first failing pixel that a pass recorded in
    /// `status` (a value other than `u32::MAX`).
    pub fn read_frame(
        &self,
        status: &wgpu::Buffer,
        out: &wgpu::Buffer,
        width: usize,
        height: usize,
    ) -> Result<std::result::Result<crate::image::ColorImage, u32>> {
        let pixels = (width * height) as u64;
        let read = self.read(&[(status, 4), (out, pixels * 16)])?;
        let failed = u32::from_le_bytes(read[0][..4].try_into().unwrap_or([0; 4]));
        if failed != super::NO_FAILURE {
            return Ok(Err(failed));
        }
        let rgba: Vec<[f32; 4]> = bytemuck::pod_collect_to_vec(&read[1]);
        Ok(Ok(crate::image::ColorImage::from_vec(width, height, rgba)?))
    }

    /// A bind group for group 0 of `pipeline` (its layout derived from the shader) holding
    /// each `(binding, buffer)` whole.
    pub fn bind(
        &self,
        pipeline: &wgpu::ComputePipeline,
        entries: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|&(binding, buffer)| wgpu::BindGroupEntry {
                binding,
                resource: buffer.as_entire_binding(),
            })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// The workgroups of a pass with one invocation a pixel of a `width` x `height` frame in
    /// workgroups of `group_x` x 1: refused, naming `what` and the limit, where the adapter
    /// allows fewer a dimension.
    pub fn row_groups(
        &self,
        what: &str,
        width: usize,
        height: usize,
        group_x: u32,
    ) -> Result<[u32; 3]> {
        let max = self.description.limits.max_compute_workgroups_per_dimension;
        let groups = [
            u32::try_from(width.div_ceil(group_x as usize)).unwrap_or(u32::MAX),
            u32::try_from(height).unwrap_or(u32::MAX),
            1,
        ];
        if groups[0] > max || groups[1] > max {
            return Err(Error::Gpu(format!(
                "{what} needs {} x {} workgroups; {} allows {max} a dimension (max compute \
                 workgroups per dimension)",
                groups[0],
                groups[1],
                self.description.label()
            )));
        }
        Ok(groups)
    }

    /// Submits what was written and waits until the GPU has done it all.
    pub fn flush(&self) -> Result<()> {
        self.queue.submit([]);
        self.wait()
    }

    /// Waits until every submitted command has run, then [`GpuContext::check`]s.
    pub fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| {
                Error::Gpu(format!(
                    "{}: waiting for the GPU failed: {e}",
                    self.description.label()
                ))
            })?;
        self.check()
    }

    /// The first `bytes` bytes of each of `buffers` (each made with `COPY_SRC`), copied back
    /// to the CPU in one submit.
    pub fn read(&self, buffers: &[(&wgpu::Buffer, u64)]) -> Result<Vec<Vec<u8>>> {
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("gpu/download"),
            });
        let staging: Vec<(wgpu::Buffer, u64)> = buffers
            .iter()
            .map(|&(src, bytes)| {
                let size = bytes.max(4).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
                let usage = wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST;
                let dst = self.buffer("gpu/download", size, usage);
                encoder.copy_buffer_to_buffer(src, 0, &dst, 0, size);
                (dst, bytes)
            })
            .collect();
        self.queue.submit([encoder.finish()]);
        for (dst, _) in &staging {
            dst.slice(..).map_async(wgpu::MapMode::Read, |_| {});
        }
        self.wait()?;
        let mut out = Vec::with_capacity(staging.len());
        for (dst, bytes) in &staging {
            let view = dst.slice(..).get_mapped_range().map_err(|e| {
                Error::Gpu(format!(
                    "{}: reading a result back failed: {e}",
                    self.description.label()
                ))
            })?;
            out.push(view[..*bytes as usize].to_vec());
            drop(view);
            dst.unmap();
        }
        self.recycle(staging.into_iter().map(|(b, _)| b));
        Ok(out)
    }
}

/// Where a pass writes its timestamps: the [`PassTimer`]'s query set, at the beginning and the
/// end of the pass's slot.
#[derive(Clone, Copy, Debug)]
pub struct PassStamps<'q> {
    query_set: &'q wgpu::QuerySet,
    index: u32,
}

impl<'q> PassStamps<'q> {
    /// The timestamp writes of a compute pass.
    pub fn compute(self) -> wgpu::ComputePassTimestampWrites<'q> {
        wgpu::ComputePassTimestampWrites {
            query_set: self.query_set,
            beginning_of_pass_write_index: Some(2 * self.index),
            end_of_pass_write_index: Some(2 * self.index + 1),
        }
    }

    /// The timestamp writes of a render pass.
    pub fn render(self) -> wgpu::RenderPassTimestampWrites<'q> {
        wgpu::RenderPassTimestampWrites {
            query_set: self.query_set,
            beginning_of_pass_write_index: Some(2 * self.index),
            end_of_pass_write_index: Some(2 * self.index + 1),
        }
    }
}

/// The passes of one run, timed: with timestamp queries they are recorded into one command
/// buffer, each between two timestamps, and submitted once by [`PassTimer::finish`]; without,
/// each pass is submitted and waited for on its own, and timed by the wall clock around that.
pub struct PassTimer<'a> {
    ctx: &'a GpuContext,
    encoder: Option<wgpu::CommandEncoder>,
    queries: Option<wgpu::QuerySet>,
    capacity: u32,
    names: Vec<&'static str>,
    timings: Timings,
}

impl<'a> PassTimer<'a> {
    /// A timer for at most `passes` passes.
    pub fn new(ctx: &'a GpuContext, passes: u32) -> Self {
        let queries = ctx.timestamps.then(|| {
            ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2 * passes.max(1),
            })
        });
        Self {
            ctx,
            encoder: None,
            queries,
            capacity: passes,
            names: Vec::new(),
            timings: Timings::default(),
        }
    }

    /// Runs the compute pass `name` (its pipeline from [`GpuContext::pipeline`]) over
    /// `workgroups` with `bind_group` at group 0.
    pub fn dispatch(
        &mut self,
        name: &'static str,
        pipeline: &wgpu::ComputePipeline,
        bind_group: &wgpu::BindGroup,
        workgroups: [u32; 3],
    ) -> Result<()> {
        self.record(name, |encoder, stamps| {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(name),
                timestamp_writes: stamps.map(|s| s.compute()),
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, bind_group, &[]);
            pass.dispatch_workgroups(workgroups[0], workgroups[1], workgroups[2]);
        })
    }

    /// Records the pass `name` with `record`, which begins one compute or render pass on the
    /// encoder with the timestamp writes it is given (`None` without timestamp queries), and
    /// may record copies before it.
    pub fn record(
        &mut self,
        name: &'static str,
        record: impl FnOnce(&mut wgpu::CommandEncoder, Option<PassStamps<'_>>),
    ) -> Result<()> {
        let index = self.names.len() as u32;
        if index >= self.capacity {
            return Err(Error::Gpu(format!(
                "pass {name}: the timer holds {} passes",
                self.capacity
            )));
        }
        let start = Instant::now();
        let mut encoder = self.encoder.take().unwrap_or_else(|| {
            self.ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(name) })
        });
        let stamps = self
            .queries
            .as_ref()
            .map(|query_set| PassStamps { query_set, index });
        record(&mut encoder, stamps);
        self.names.push(name);
        if self.queries.is_some() {
            self.encoder = Some(encoder);
        } else {
            self.ctx.queue.submit([encoder.finish()]);
            self.ctx.wait()?;
            self.timings
                .add_with(name, start.elapsed().as_secs_f64() * 1e3, Clock::SubmitWait);
        }
        Ok(())
    }

    /// Runs `passes` in order, each `(name, pipeline, bind group, workgroups)` as
    /// [`PassTimer::dispatch`] takes them, and returns each pass's time.
    pub fn run(
        ctx: &'a GpuContext,
        passes: &[(
            &'static str,
            &wgpu::ComputePipeline,
            &wgpu::BindGroup,
            [u32; 3],
        )],
    ) -> Result<Timings> {
        let mut timer = Self::new(ctx, passes.len() as u32);
        for &(name, pipeline, group, workgroups) in passes {
            timer.dispatch(name, pipeline, group, workgroups)?;
        }
        timer.finish()
    }

    /// Submits what is recorded, waits for it, and returns each pass's time.
    pub fn finish(mut self) -> Result<Timings> {
        let (Some(queries), Some(mut encoder)) = (self.queries.take(), self.encoder.take()) else {
            self.ctx.check()?;
            return Ok(self.timings);
        };
        let count = 2 * self.names.len() as u32;
        let bytes = u64::from(count) * 8;
        let resolve = self.ctx.buffer(
            "pass timestamps",
            bytes,
            wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
        );
        encoder.resolve_query_set(&queries, 0..count, &resolve, 0);
        self.ctx.queue.submit([encoder.finish()]);
        let ticks = self.ctx.read(&[(&resolve, bytes)])?;
        self.ctx.recycle([resolve]);
        let period_ns = f64::from(self.ctx.queue.get_timestamp_period());
        for (i, name) in self.names.iter().enumerate() {
            let at = |k: usize| {
                let b = &ticks[0][8 * k..8 * k + 8];
                u64::from_le_bytes(b.try_into().unwrap_or([0; 8]))
            };
            let ns = at(2 * i + 1).saturating_sub(at(2 * i)) as f64 * period_ns;
            self.timings.add_with(name, ns * 1e-6, Clock::GpuTimestamps);
        }
        Ok(self.timings)
    }
}

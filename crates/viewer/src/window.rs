//! The windowed front end: a winit window with a wgpu surface. Mouse and keys become
//! [`Action`]s; every redraw renders one [`Viewer`] frame, tone-maps it (display exposure, sRGB)
//! into a texture and draws it with `shaders/blit.wgsl`.
//!
//! Controls (also printed by `H`):
//! - left drag: orbit; right drag (or Shift + left drag): pan; wheel: zoom;
//! - Ctrl + left drag or arrow keys: sun azimuth / elevation; Space: play/pause the sun;
//! - D: play/pause the density animation; 1 / 2 / 3 / 4: photon mapping with final gathering /
//!   path tracing / RPNN / ray-marched photon mapping;
//! - + / −: exposure; P: screenshot (PNG); S: save camera and sun to a scene TOML; Esc / Q: quit.
//!
//! Robustness: a zero-sized (minimised) window renders nothing until it is restored; an
//! outdated or lost surface is reconfigured or recreated; a timeout or occlusion skips the frame;
//! a lost device ends the viewer with an error; no display or no adapter gives a clear error.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use nimbus_gpu::Gpu;
use nimbus_scene::Scene;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use crate::script::{Action, Script, ViewMode};
use crate::viewer::{SceneSource, Viewer, ViewerError, ViewerOptions};

/// Extra settings of a windowed session.
#[derive(Debug, Clone, Default)]
pub struct WindowOptions {
    pub script: Script,
    /// Close after this many frames (scripted sessions, tests).
    pub frames: Option<u32>,
    /// Saved when the viewer closes.
    pub screenshot: Option<PathBuf>,
    /// Print each frame's status line to stdout as well as the title.
    pub log: bool,
}

pub const HELP: &str = "\
nimbus view — left drag: orbit | right drag / Shift+drag: pan | wheel: zoom
  Ctrl+drag or arrows: sun azimuth/elevation | Space: play/pause sun | D: play/pause density
  1/2/3/4/5: photon mapping (gathered) / path tracing / RPNN / photon mapping (ray marched) /
  RPNN with the paper's sky directions
  +/-: exposure | P: screenshot | S: save scene
  H: this help | Esc/Q: quit";

/// Opens the window and runs until it is closed.
pub fn run(
    scene: Scene,
    source: Option<SceneSource>,
    opts: ViewerOptions,
    wopts: WindowOptions,
) -> Result<(), ViewerError> {
    let event_loop = EventLoop::new().map_err(|e| {
        ViewerError::Other(format!(
            "cannot open a window ({e}); is a display available (DISPLAY)? \
             `nimbus view --headless` runs without one"
        ))
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let mut app = App {
        init: Some((scene, source, opts)),
        wopts,
        running: None,
        error: None,
        input: Input::default(),
        last: Instant::now(),
        frame: 0,
        shots: 0,
        present_ms: 0.0,
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| ViewerError::Other(format!("window event loop: {e}")))?;
    match app.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

#[derive(Default)]
struct Input {
    left: bool,
    right: bool,
    shift: bool,
    ctrl: bool,
    cursor: Option<(f64, f64)>,
}

struct Running {
    window: Arc<Window>,
    instance: wgpu::Instance,
    surface: wgpu::Surface<'static>,
    adapter: wgpu::Adapter,
    config: wgpu::SurfaceConfiguration,
    gpu: &'static Gpu,
    viewer: Viewer<'static>,
    blit: Blit,
    lost: Arc<AtomicBool>,
    minimised: bool,
}

struct Blit {
    pipeline: wgpu::RenderPipeline,
    texture_format: wgpu::TextureFormat,
    texture: Option<(wgpu::Texture, wgpu::BindGroup, u32, u32)>,
}

struct App {
    init: Option<(Scene, Option<SceneSource>, ViewerOptions)>,
    wopts: WindowOptions,
    running: Option<Running>,
    error: Option<ViewerError>,
    input: Input,
    last: Instant,
    frame: u32,
    shots: u32,
    /// Tone mapping, upload and drawing of the previous frame.
    present_ms: f64,
}

fn surface_config(
    surface: &wgpu::Surface<'_>,
    adapter: &wgpu::Adapter,
    w: u32,
    h: u32,
) -> Result<wgpu::SurfaceConfiguration, ViewerError> {
    let caps = surface.get_capabilities(adapter);
    let format = caps
        .formats
        .iter()
        .copied()
        .find(|f| {
            matches!(
                f,
                wgpu::TextureFormat::Rgba8Unorm
                    | wgpu::TextureFormat::Bgra8Unorm
                    | wgpu::TextureFormat::Rgba8UnormSrgb
                    | wgpu::TextureFormat::Bgra8UnormSrgb
            )
        })
        .or_else(|| caps.formats.first().copied())
        .ok_or_else(|| ViewerError::Other("the window surface offers no format".into()))?;
    let mut config = surface
        .get_default_config(adapter, w.max(1), h.max(1))
        .ok_or_else(|| ViewerError::Other("the window surface is not supported".into()))?;
    config.format = format;
    config.present_mode = wgpu::PresentMode::AutoVsync;
    Ok(config)
}

impl Blit {
    fn new(gpu: &Gpu, surface_format: wgpu::TextureFormat) -> Self {
        let module = gpu
            .device
            .create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("blit"),
                source: wgpu::ShaderSource::Wgsl(nimbus_gpu::shaders::source("blit.wgsl").into()),
            });
        let pipeline = gpu
            .device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some("blit"),
                layout: None,
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some("vs"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some("fs"),
                    compilation_options: Default::default(),
                    targets: &[Some(surface_format.into())],
                }),
                primitive: Default::default(),
                depth_stencil: None,
                multisample: Default::default(),
                multiview_mask: None,
                cache: None,
            });
        // The frame bytes are sRGB-encoded; an sRGB texture decodes them for an sRGB surface
        // (which encodes again), a plain one passes them through to a plain surface.
        let texture_format = if surface_format.is_srgb() {
            wgpu::TextureFormat::Rgba8UnormSrgb
        } else {
            wgpu::TextureFormat::Rgba8Unorm
        };
        Self {
            pipeline,
            texture_format,
            texture: None,
        }
    }

    fn upload(&mut self, gpu: &Gpu, rgba: &[u8], w: u32, h: u32) {
        if !matches!(&self.texture, Some((_, _, tw, th)) if *tw == w && *th == h) {
            let texture = gpu.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("frame"),
                size: wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: self.texture_format,
                usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
                view_formats: &[],
            });
            let view = texture.create_view(&Default::default());
            let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("blit"),
                layout: &self.pipeline.get_bind_group_layout(0),
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&view),
                }],
            });
            self.texture = Some((texture, bind, w, h));
        }
        let (texture, _, _, _) = self.texture.as_ref().expect("created above");
        gpu.queue.write_texture(
            texture.as_image_copy(),
            rgba,
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * w),
                rows_per_image: Some(h),
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
    }

    fn draw(&self, gpu: &Gpu, target: &wgpu::TextureView) {
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("blit"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::BLACK),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            if let Some((_, bind, _, _)) = &self.texture {
                pass.set_pipeline(&self.pipeline);
                pass.set_bind_group(0, bind, &[]);
                pass.draw(0..3, 0..1);
            }
        }
        gpu.queue.submit([enc.finish()]);
    }
}

impl App {
    fn fail(&mut self, event_loop: &ActiveEventLoop, e: ViewerError) {
        if self.error.is_none() {
            self.error = Some(e);
        }
        event_loop.exit();
    }

    fn start(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let Some((scene, source, opts)) = self.init.take() else {
            return Ok(());
        };
        let (w, h) = (scene.camera.width as u32, scene.camera.height as u32);
        let window = Arc::new(
            event_loop
                .create_window(
                    Window::default_attributes()
                        .with_title("nimbus view")
                        .with_inner_size(PhysicalSize::new(w, h)),
                )
                .map_err(|e| ViewerError::Other(format!("cannot create a window: {e}")))?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance
            .create_surface(window.clone())
            .map_err(|e| ViewerError::Other(format!("cannot create a GPU surface: {e}")))?;
        let (gpu, adapter) = Gpu::for_surface(&instance, Some(&surface))?;
        // The viewer borrows the device for the rest of the process.
        let gpu: &'static Gpu = Box::leak(Box::new(gpu));
        let lost = Arc::new(AtomicBool::new(false));
        let flag = lost.clone();
        gpu.device.set_device_lost_callback(move |reason, msg| {
            eprintln!("GPU device lost ({reason:?}): {msg}");
            flag.store(true, Ordering::SeqCst);
        });
        let size = window.inner_size();
        let config = surface_config(&surface, &adapter, size.width, size.height)?;
        let minimised = size.width == 0 || size.height == 0;
        if !minimised {
            surface.configure(&gpu.device, &config);
        }
        let blit = Blit::new(gpu, config.format);
        let mut viewer = Viewer::new(gpu, scene, source, opts)?;
        if !minimised && (size.width, size.height) != (w, h) {
            viewer.apply(&Action::Resize {
                width: size.width,
                height: size.height,
            })?;
        }
        println!("{HELP}");
        println!("adapter: {}", gpu.describe());
        self.running = Some(Running {
            window,
            instance,
            surface,
            adapter,
            config,
            gpu,
            viewer,
            blit,
            lost,
            minimised,
        });
        self.last = Instant::now();
        Ok(())
    }

    fn redraw(&mut self, event_loop: &ActiveEventLoop) -> Result<(), ViewerError> {
        let Some(r) = self.running.as_mut() else {
            return Ok(());
        };
        if r.lost.load(Ordering::SeqCst) {
            return Err(ViewerError::Other(
                "the GPU device was lost (driver reset or removal); restart the viewer".into(),
            ));
        }
        if r.minimised {
            return Ok(());
        }
        let now = Instant::now();
        let dt = (now - self.last).as_secs_f64().min(0.25);
        self.last = now;
        crate::run_frame(&mut r.viewer, self.wopts.script.due(self.frame), dt)?;
        self.frame += 1;
        let line = r.viewer.status_line();
        let title = format!("nimbus view — {line} | present {:.1} ms", self.present_ms);
        r.window.set_title(&title);
        if self.wopts.log {
            println!(
                "frame {}: {line} | present {:.1} ms",
                self.frame - 1,
                self.present_ms
            );
        }
        let t_present = Instant::now();
        let img = r.viewer.image();
        let rgba = to_rgba8(img, r.viewer.exposure());
        r.blit
            .upload(r.gpu, &rgba, img.width as u32, img.height as u32);
        let frame = match r.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t) => Some((t, false)),
            wgpu::CurrentSurfaceTexture::Suboptimal(t) => Some((t, true)),
            wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => None,
            wgpu::CurrentSurfaceTexture::Outdated => {
                r.surface.configure(&r.gpu.device, &r.config);
                None
            }
            wgpu::CurrentSurfaceTexture::Lost => {
                r.surface = r
                    .instance
                    .create_surface(r.window.clone())
                    .map_err(|e| ViewerError::Other(format!("recreating the surface: {e}")))?;
                r.config = surface_config(&r.surface, &r.adapter, r.config.width, r.config.height)?;
                r.surface.configure(&r.gpu.device, &r.config);
                None
            }
            other => {
                return Err(ViewerError::Other(format!(
                    "the window surface failed: {other:?}"
                )));
            }
        };
        if let Some((texture, suboptimal)) = frame {
            let view = texture.texture.create_view(&Default::default());
            r.blit.draw(r.gpu, &view);
            r.window.pre_present_notify();
            r.gpu.queue.present(texture);
            if suboptimal {
                r.surface.configure(&r.gpu.device, &r.config);
            }
        }
        self.present_ms = t_present.elapsed().as_secs_f64() * 1e3;
        if r.viewer.quit_requested() || self.wopts.frames.is_some_and(|n| self.frame >= n) {
            if let Some(p) = &self.wopts.screenshot {
                r.viewer.screenshot(p)?;
            }
            event_loop.exit();
        }
        Ok(())
    }

    fn resize(&mut self, size: PhysicalSize<u32>) -> Result<(), ViewerError> {
        let Some(r) = self.running.as_mut() else {
            return Ok(());
        };
        r.minimised = size.width == 0 || size.height == 0;
        if r.minimised {
            return Ok(());
        }
        r.config.width = size.width;
        r.config.height = size.height;
        r.surface.configure(&r.gpu.device, &r.config);
        r.viewer.apply(&Action::Resize {
            width: size.width,
            height: size.height,
        })
    }

    fn key(&mut self, key: &Key) -> Result<Option<Action>, ViewerError> {
        let Some(r) = self.running.as_mut() else {
            return Ok(None);
        };
        Ok(match key {
            Key::Named(NamedKey::Escape) => Some(Action::Quit),
            Key::Named(NamedKey::Space) => Some(Action::ToggleSunMotion),
            Key::Named(NamedKey::ArrowLeft) => Some(sun_move(-5.0, 0.0)),
            Key::Named(NamedKey::ArrowRight) => Some(sun_move(5.0, 0.0)),
            Key::Named(NamedKey::ArrowUp) => Some(sun_move(0.0, 5.0)),
            Key::Named(NamedKey::ArrowDown) => Some(sun_move(0.0, -5.0)),
            Key::Character(c) => match c.as_str() {
                "q" | "Q" => Some(Action::Quit),
                "d" | "D" => Some(Action::ToggleDensityAnimation),
                "1" => Some(Action::Method(ViewMode::Pm)),
                "2" => Some(Action::Method(ViewMode::Pt)),
                "3" => Some(Action::Method(ViewMode::Rpnn)),
                "4" => Some(Action::Method(ViewMode::PmMarch)),
                "5" => Some(Action::Method(ViewMode::RpnnDirs)),
                "+" | "=" => {
                    r.viewer.scale_exposure(2f64.sqrt());
                    None
                }
                "-" | "_" => {
                    r.viewer.scale_exposure(1.0 / 2f64.sqrt());
                    None
                }
                "p" | "P" => {
                    self.shots += 1;
                    let p = PathBuf::from(format!("nimbus-view-{:03}.png", self.shots));
                    println!("screenshot: {}", p.display());
                    Some(Action::Screenshot(p))
                }
                "s" | "S" => {
                    self.shots += 1;
                    let p = PathBuf::from(format!("nimbus-view-{:03}.toml", self.shots));
                    println!("scene saved: {}", p.display());
                    Some(Action::SaveScene(p))
                }
                "h" | "H" => {
                    println!("{HELP}");
                    None
                }
                _ => None,
            },
            _ => None,
        })
    }
}

/// Display encoding, in parallel rows: sRGB(clamp(exposure · L)) as 8-bit RGBA, the same
/// mapping as the PNG writer.
fn to_rgba8(img: &nimbus_scene::Image, exposure: f64) -> Vec<u8> {
    use rayon::prelude::*;
    let mut out = vec![255u8; img.pixels.len() * 4];
    out.par_chunks_mut(4 * img.width)
        .zip(img.pixels.par_chunks(img.width))
        .for_each(|(row, px)| {
            for (o, p) in row.chunks_exact_mut(4).zip(px) {
                for c in 0..3 {
                    let v = (p[c] as f64 * exposure).clamp(0.0, 1.0);
                    o[c] = (nimbus_scene::image::srgb_oetf(v) * 255.0).round() as u8;
                }
            }
        });
    out
}

fn sun_move(az: f64, el: f64) -> Action {
    Action::MoveSun {
        azimuth_deg: az,
        elevation_deg: el,
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if let Err(e) = self.start(event_loop) {
            self.fail(event_loop, e);
        }
    }

    fn about_to_wait(&mut self, _event_loop: &ActiveEventLoop) {
        if let Some(r) = &self.running {
            r.window.request_redraw();
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let result = match event {
            WindowEvent::CloseRequested => {
                event_loop.exit();
                Ok(())
            }
            WindowEvent::Resized(size) => self.resize(size),
            WindowEvent::RedrawRequested => self.redraw(event_loop),
            WindowEvent::ModifiersChanged(m) => {
                self.input.shift = m.state().shift_key();
                self.input.ctrl = m.state().control_key();
                Ok(())
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match self.key(&event.logical_key) {
                    Ok(Some(a)) => self.apply(a),
                    Ok(None) => Ok(()),
                    Err(e) => Err(e),
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let down = state == ElementState::Pressed;
                match button {
                    MouseButton::Left => self.input.left = down,
                    MouseButton::Right => self.input.right = down,
                    _ => {}
                }
                Ok(())
            }
            WindowEvent::CursorMoved { position, .. } => {
                let (x, y) = (position.x, position.y);
                let action = match self.input.cursor {
                    Some((px, py)) if self.input.left || self.input.right => {
                        let (dx, dy) = (x - px, y - py);
                        let h = self
                            .running
                            .as_ref()
                            .map_or(600.0, |r| r.config.height as f64);
                        if self.input.right || (self.input.left && self.input.shift) {
                            Some(Action::Pan {
                                right: -dx / h,
                                up: dy / h,
                            })
                        } else if self.input.ctrl {
                            Some(sun_move(dx * 0.3, -dy * 0.3))
                        } else {
                            Some(Action::Orbit {
                                yaw_deg: -dx * 0.3,
                                pitch_deg: dy * 0.3,
                            })
                        }
                    }
                    _ => None,
                };
                self.input.cursor = Some((x, y));
                match action {
                    Some(a) => self.apply(a),
                    None => Ok(()),
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y as f64,
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.apply(Action::Zoom {
                    factor: 0.9f64.powf(lines),
                })
            }
            _ => Ok(()),
        };
        if let Err(e) = result {
            self.fail(event_loop, e);
        }
    }
}

impl App {
    fn apply(&mut self, a: Action) -> Result<(), ViewerError> {
        match self.running.as_mut() {
            Some(r) => r.viewer.apply(&a),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_encoding_matches_the_png_writer() {
        let mut img = nimbus_scene::Image::new(7, 3);
        for (k, p) in img.pixels.iter_mut().enumerate() {
            *p = [k as f32 * 0.05, 0.001 * k as f32, 2.0 - k as f32 * 0.1];
        }
        let rgba = to_rgba8(&img, 1.3);
        let rgb = img.to_srgb8(1.3);
        for (a, b) in rgba.chunks_exact(4).zip(rgb.chunks_exact(3)) {
            assert_eq!(&a[..3], b);
            assert_eq!(a[3], 255);
        }
    }
}

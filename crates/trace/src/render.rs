//! Image rendering: 16×16 tiles in parallel (rayon), each pixel's samples from their own random
//! stream ([`Pcg32::for_sample`]) so the image depends only on the seed, never on the thread
//! count; a progress bar; mean RGB and the variance of each pixel's mean luminance.

use nimbus_scene::clock::Instant;

use nimbus_scene::{Cancel, Cancelled, Image, Scene};
use rayon::prelude::*;

use crate::integrator::{PathStats, PathTracer};
use crate::rng::Pcg32;

const TILE: usize = 16;

/// One pixel's sums over the samples of one call: (index, Σ RGB, Σ lum, Σ lum²).
type PixelSums = (usize, [f64; 3], f64, f64);

/// What to render.
#[derive(Debug, Clone)]
pub struct RenderOptions {
    pub spp: u32,
    pub seed: u64,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

impl RenderOptions {
    /// The scene's own settings, no progress bar.
    pub fn from_scene(scene: &Scene) -> Self {
        Self {
            spp: scene.render.spp,
            seed: scene.render.seed,
            progress: false,
        }
    }
}

/// Work counters of a render.
#[derive(Debug, Clone, Copy, Default)]
pub struct RenderStats {
    pub paths: u64,
    pub scatterings: u64,
    pub seconds: f64,
}

impl RenderStats {
    pub fn paths_per_second(&self) -> f64 {
        self.paths as f64 / self.seconds.max(1e-9)
    }
}

/// A rendered image with per-pixel variance of the mean luminance.
#[derive(Debug, Clone)]
pub struct RenderOutput {
    pub image: Image,
    pub variance: Vec<f32>,
    pub stats: RenderStats,
}

/// Renders `scene` with the path tracer.
pub fn render(scene: &Scene, opts: &RenderOptions) -> RenderOutput {
    render_with(&PathTracer::new(scene), opts)
}

/// Per-pixel running sums of a progressive render: Σ RGB, Σ lum, Σ lum² over `samples`
/// samples per pixel.
#[derive(Debug, Clone)]
pub struct Sums {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<[f64; 3]>,
    pub lum: Vec<f64>,
    pub lum2: Vec<f64>,
    pub samples: u64,
}

impl Sums {
    /// Empty sums for a `width`×`height` image.
    pub fn new(width: usize, height: usize) -> Self {
        let n = width * height;
        Self {
            width,
            height,
            rgb: vec![[0.0; 3]; n],
            lum: vec![0.0; n],
            lum2: vec![0.0; n],
            samples: 0,
        }
    }

    /// The mean image and the variance of each pixel's mean luminance (0 below two samples).
    pub fn image(&self) -> (Image, Vec<f32>) {
        let n = self.samples.max(1) as f64;
        let mut image = Image::new(self.width, self.height);
        let mut variance = vec![0.0f32; self.width * self.height];
        for (i, (px, var)) in image.pixels.iter_mut().zip(&mut variance).enumerate() {
            *px = self.rgb[i].map(|v| (v / n) as f32);
            let mean = self.lum[i] / n;
            *var = if self.samples > 1 {
                ((self.lum2[i] / n - mean * mean).max(0.0) / (n - 1.0)) as f32
            } else {
                0.0
            };
        }
        (image, variance)
    }
}

/// Renders with a given tracer (for example one without empty-space skipping).
pub fn render_with(tracer: &PathTracer, opts: &RenderOptions) -> RenderOutput {
    let cam = &tracer.scene.camera;
    let mut sums = Sums::new(cam.width, cam.height);
    let stats = accumulate(tracer, opts, &mut sums);
    let (image, variance) = sums.image();
    RenderOutput {
        image,
        variance,
        stats,
    }
}

/// Adds `opts.spp` samples per pixel to `sums` (progressive rendering): sample s of pixel p is
/// sample `sums.samples + s` of its stream, so accumulating in steps gives the image one call
/// gives.
pub fn accumulate(tracer: &PathTracer, opts: &RenderOptions, sums: &mut Sums) -> RenderStats {
    accumulate_cancellable(tracer, opts, sums, &Cancel::never()).expect("never cancelled")
}

/// [`accumulate`], checking `cancel` before each pixel: once it is set the call returns
/// [`Cancelled`] and `sums` are left as they were (no sample of this call is added).
pub fn accumulate_cancellable(
    tracer: &PathTracer,
    opts: &RenderOptions,
    sums: &mut Sums,
    cancel: &Cancel,
) -> Result<RenderStats, Cancelled> {
    let cam = &tracer.scene.camera;
    let (w, h) = (cam.width, cam.height);
    assert_eq!(
        (sums.width, sums.height),
        (w, h),
        "sums of another image size"
    );
    let first = sums.samples;
    let tiles: Vec<(usize, usize)> = (0..h.div_ceil(TILE))
        .flat_map(|ty| (0..w.div_ceil(TILE)).map(move |tx| (tx * TILE, ty * TILE)))
        .collect();
    let bar = crate::progress::Bar::new(tiles.len() as u64, opts.progress);
    let start = Instant::now();
    let spp = opts.spp.max(1);
    let results: Vec<(Vec<PixelSums>, u64)> = tiles
        .par_iter()
        .map(|&(x0, y0)| {
            let mut out = Vec::with_capacity(TILE * TILE);
            let mut scat = 0u64;
            for y in y0..(y0 + TILE).min(h) {
                for x in x0..(x0 + TILE).min(w) {
                    if cancel.is_cancelled() {
                        return (out, scat);
                    }
                    let pixel = (y * w + x) as u64;
                    let mut sum = [0.0f64; 3];
                    let (mut ls, mut ls2) = (0.0f64, 0.0f64);
                    for s in 0..spp as u64 {
                        let mut rng = Pcg32::for_sample(opts.seed, pixel, first + s);
                        let [jx, jy] = rng.next2();
                        let d = cam.ray_dir(x as f64 + jx, y as f64 + jy);
                        let mut st = PathStats::default();
                        let l = tracer.radiance(cam.origin, d, &mut rng, &mut st);
                        scat += st.scatterings;
                        sum[0] += l.x;
                        sum[1] += l.y;
                        sum[2] += l.z;
                        let lum = (l.x + l.y + l.z) / 3.0;
                        ls += lum;
                        ls2 += lum * lum;
                    }
                    out.push((pixel as usize, sum, ls, ls2));
                }
            }
            bar.inc();
            (out, scat)
        })
        .collect();
    bar.finish();
    cancel.check()?;
    let mut stats = RenderStats {
        paths: (w * h) as u64 * spp as u64,
        ..Default::default()
    };
    for (tile, scat) in results {
        stats.scatterings += scat;
        for (i, c, l, l2) in tile {
            for (s, v) in sums.rgb[i].iter_mut().zip(c) {
                *s += v;
            }
            sums.lum[i] += l;
            sums.lum2[i] += l2;
        }
    }
    sums.samples += spp as u64;
    stats.seconds = start.elapsed().as_secs_f64();
    Ok(stats)
}

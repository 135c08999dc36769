//! Software rendering of triangle meshes to PNG: orthographic front and side views,
//! z-buffered, smooth Lambert shading lit from the camera, 2x2 supersampled.

use glam::{Vec2, Vec3};

/// Skin-like colour for bodies.
pub const BODY_COLOUR: [u8; 3] = [214, 180, 156];
/// Blue for garments and overlays.
pub const GARMENT_COLOUR: [u8; 3] = [70, 120, 200];

/// One mesh to draw.
#[derive(Debug, Clone, Copy)]
pub struct Layer<'a> {
    /// Vertex positions (m, Y up).
    pub vertices: &'a [Vec3],
    /// Triangles.
    pub triangles: &'a [[u32; 3]],
    /// Base colour (sRGB).
    pub colour: [u8; 3],
    /// Per-vertex colours (sRGB) in place of `colour`, interpolated over faces.
    pub vertex_colours: Option<&'a [[u8; 3]]>,
    /// Per-vertex values (e.g. an error in cm) interpolated into [`Values`] by
    /// [`render_values`].
    pub values: Option<&'a [f32]>,
}

impl<'a> Layer<'a> {
    /// A layer from a mesh and a colour.
    pub fn new(vertices: &'a [Vec3], triangles: &'a [[u32; 3]], colour: [u8; 3]) -> Self {
        Self {
            vertices,
            triangles,
            colour,
            vertex_colours: None,
            values: None,
        }
    }

    /// Colours each vertex with `colours` (one per vertex) and records `values`.
    pub fn with_vertex_colours(mut self, colours: &'a [[u8; 3]], values: &'a [f32]) -> Self {
        self.vertex_colours = Some(colours);
        self.values = Some(values);
        self
    }
}

/// A float image of the values of the front-most layer that carries values (NaN where
/// there is none), the same size as the colour image.
#[derive(Debug, Clone, PartialEq)]
pub struct Values {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major values.
    pub data: Vec<f32>,
}

/// A camera direction. Views are orthographic with Y up on screen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// Looking at the face: camera on +Z looking towards -Z; screen x = world x.
    Front,
    /// Looking at the character's right side: camera on -X; the face points right.
    Side,
}

impl View {
    /// Screen coordinates `(x, y)` and depth (larger is nearer the camera) of a point.
    fn project(self, p: Vec3) -> (Vec2, f32) {
        match self {
            View::Front => (Vec2::new(p.x, p.y), p.z),
            View::Side => (Vec2::new(p.z, p.y), -p.x),
        }
    }

    /// Unit vector from the scene towards the camera.
    fn towards_camera(self) -> Vec3 {
        match self {
            View::Front => Vec3::Z,
            View::Side => -Vec3::X,
        }
    }
}

/// How to render.
#[derive(Debug, Clone)]
pub struct RenderOptions {
    /// Views side by side, left to right (default front and side).
    pub views: Vec<View>,
    /// Height of the image in pixels (default 480).
    pub height: u32,
    /// Empty space around the meshes, as a fraction of their height (default 0.04).
    pub margin: f32,
    /// Background colour (default light grey).
    pub background: [u8; 3],
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            views: vec![View::Front, View::Side],
            height: 480,
            margin: 0.04,
            background: [242, 242, 242],
        }
    }
}

/// An RGB image.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major RGB bytes.
    pub rgb: Vec<u8>,
}

/// Rendering failed.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// Nothing to draw, or input that cannot be drawn.
    #[error("cannot render: {0}")]
    Empty(&'static str),
    /// PNG encoding failed.
    #[error("PNG encoding: {0}")]
    Png(#[from] png::EncodingError),
}

const SUPERSAMPLE: u32 = 2;

/// Largest image height accepted (pixels).
pub const MAX_HEIGHT: u32 = 2048;

/// Renders the layers into one image with the views side by side; all views share one
/// scale so heights compare across views.
pub fn render(layers: &[Layer<'_>], opts: &RenderOptions) -> Result<Image, RenderError> {
    render_values(layers, opts).map(|(image, _)| image)
}

/// [`render`], and the layers' per-vertex values as a float image.
pub fn render_values(
    layers: &[Layer<'_>],
    opts: &RenderOptions,
) -> Result<(Image, Values), RenderError> {
    let points = || layers.iter().flat_map(|l| l.vertices.iter().copied());
    if points().next().is_none() || opts.views.is_empty() {
        return Err(RenderError::Empty("no vertices or no views"));
    }
    if points().any(|p| !p.is_finite()) {
        return Err(RenderError::Empty("non-finite vertex positions"));
    }
    if layers.iter().any(|l| {
        l.vertex_colours
            .is_some_and(|c| c.len() != l.vertices.len())
            || l.values.is_some_and(|v| v.len() != l.vertices.len())
    }) {
        return Err(RenderError::Empty(
            "per-vertex colours or values do not match the vertices",
        ));
    }
    if layers.iter().any(|l| {
        l.triangles
            .iter()
            .flatten()
            .any(|&i| i as usize >= l.vertices.len())
    }) {
        return Err(RenderError::Empty("a triangle index is out of range"));
    }
    if !(16..=MAX_HEIGHT).contains(&opts.height) {
        return Err(RenderError::Empty(
            "the image height must lie in 16 to 2048 pixels",
        ));
    }
    let normals: Vec<Vec<Vec3>> = layers
        .iter()
        .map(|l| sim::mesh::vertex_normals(l.vertices, l.triangles))
        .collect();
    // Per-view screen bounds, shared vertical range and scale.
    let bounds: Vec<(Vec2, Vec2)> = opts
        .views
        .iter()
        .map(|v| {
            points().fold(
                (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN)),
                |(lo, hi), p| {
                    let s = v.project(p).0;
                    (lo.min(s), hi.max(s))
                },
            )
        })
        .collect();
    let y_lo = bounds.iter().map(|b| b.0.y).fold(f32::MAX, f32::min);
    let y_hi = bounds.iter().map(|b| b.1.y).fold(f32::MIN, f32::max);
    let extent = (y_hi - y_lo)
        .max(bounds.iter().map(|b| b.1.x - b.0.x).fold(0.0, f32::max))
        .max(1e-6);
    let margin = opts.margin * extent;
    let h_px = opts.height * SUPERSAMPLE;
    let scale = h_px as f32 / (y_hi - y_lo + 2.0 * margin).max(extent * 0.25);
    let widths: Vec<u32> = bounds
        .iter()
        .map(|b| (((b.1.x - b.0.x) + 2.0 * margin) * scale).ceil().max(8.0) as u32)
        .collect();
    let w_px: u32 = widths.iter().sum();
    let (w_us, h_us) = (w_px as usize, h_px as usize);
    let mut colour = vec![Vec3::from_array(opts.background.map(|c| c as f32 / 255.0)); w_us * h_us];
    let mut depth = vec![f32::MIN; w_us * h_us];
    let mut value = vec![f32::NAN; w_us * h_us];

    let mut x0 = 0u32;
    for ((view, b), &w) in opts.views.iter().zip(&bounds).zip(&widths) {
        let to_px = |s: Vec2| {
            Vec2::new(
                x0 as f32 + (s.x - b.0.x + margin) * scale,
                (y_hi + margin - s.y) * scale,
            )
        };
        let light = (view.towards_camera() + Vec3::new(0.25, 0.45, 0.0)).normalize();
        for (layer, normals) in layers.iter().zip(&normals) {
            let base = Vec3::from_array(layer.colour.map(|c| c as f32 / 255.0));
            let proj: Vec<(Vec2, f32)> = layer
                .vertices
                .iter()
                .map(|&p| {
                    let (s, d) = view.project(p);
                    (to_px(s), d)
                })
                .collect();
            for t in layer.triangles {
                let [a, bb, c] = t.map(|i| i as usize);
                let (pa, pb, pc) = (proj[a], proj[bb], proj[c]);
                let area = (pb.0 - pa.0).perp_dot(pc.0 - pa.0);
                if area.abs() < 1e-12 {
                    continue;
                }
                let lo = pa.0.min(pb.0).min(pc.0).max(Vec2::new(x0 as f32, 0.0));
                let hi =
                    pa.0.max(pb.0)
                        .max(pc.0)
                        .min(Vec2::new((x0 + w) as f32 - 1.0, h_px as f32 - 1.0));
                if lo.x > hi.x || lo.y > hi.y {
                    continue;
                }
                for py in lo.y.floor() as u32..=hi.y.ceil() as u32 {
                    for px in lo.x.floor() as u32..=hi.x.ceil() as u32 {
                        let q = Vec2::new(px as f32 + 0.5, py as f32 + 0.5);
                        let w0 = (pb.0 - q).perp_dot(pc.0 - q) / area;
                        let w1 = (pc.0 - q).perp_dot(pa.0 - q) / area;
                        let w2 = 1.0 - w0 - w1;
                        if w0 < -1e-6 || w1 < -1e-6 || w2 < -1e-6 {
                            continue;
                        }
                        let z = w0 * pa.1 + w1 * pb.1 + w2 * pc.1;
                        let k = py as usize * w_us + px as usize;
                        if z <= depth[k] {
                            continue;
                        }
                        depth[k] = z;
                        let n = (normals[a] * w0 + normals[bb] * w1 + normals[c] * w2)
                            .normalize_or_zero();
                        // Two-sided: open garments show their inside in the same colour, darker.
                        let facing = n.dot(view.towards_camera());
                        let lambert = n.dot(light).abs();
                        let shade = if facing >= 0.0 {
                            0.25 + 0.75 * lambert
                        } else {
                            0.15 + 0.45 * lambert
                        };
                        let base = match layer.vertex_colours {
                            Some(vc) => {
                                let f =
                                    |i: usize| Vec3::from_array(vc[i].map(|c| c as f32 / 255.0));
                                f(a) * w0 + f(bb) * w1 + f(c) * w2
                            }
                            None => base,
                        };
                        colour[k] = base * shade;
                        value[k] = match layer.values {
                            Some(v) => v[a] * w0 + v[bb] * w1 + v[c] * w2,
                            None => f32::NAN,
                        };
                    }
                }
            }
        }
        x0 += w;
    }
    // Downsample.
    let (w_out, h_out) = (w_px / SUPERSAMPLE, h_px / SUPERSAMPLE);
    let mut rgb = Vec::with_capacity((w_out * h_out * 3) as usize);
    let mut values = Vec::with_capacity((w_out * h_out) as usize);
    for y in 0..h_out {
        for x in 0..w_out {
            let mut acc = Vec3::ZERO;
            let (mut vsum, mut vn) = (0.0f32, 0u32);
            for dy in 0..SUPERSAMPLE {
                for dx in 0..SUPERSAMPLE {
                    let (sy, sx) = (
                        (y * SUPERSAMPLE + dy) as usize,
                        (x * SUPERSAMPLE + dx) as usize,
                    );
                    acc += colour[sy * w_us + sx];
                    let v = value[sy * w_us + sx];
                    if v.is_finite() {
                        vsum += v;
                        vn += 1;
                    }
                }
            }
            values.push(if vn > 0 { vsum / vn as f32 } else { f32::NAN });
            let c = acc / (SUPERSAMPLE * SUPERSAMPLE) as f32;
            rgb.extend(
                c.to_array()
                    .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8),
            );
        }
    }
    Ok((
        Image {
            width: w_out,
            height: h_out,
            rgb,
        },
        Values {
            width: w_out,
            height: h_out,
            data: values,
        },
    ))
}

/// Places images in a grid, `columns` per row, on a background colour.
pub fn grid(images: &[Image], columns: usize, background: [u8; 3]) -> Image {
    let columns = columns.max(1);
    let cell_w = images.iter().map(|i| i.width).max().unwrap_or(1);
    let cell_h = images.iter().map(|i| i.height).max().unwrap_or(1);
    let rows = images.len().div_ceil(columns).max(1);
    let at = images.iter().enumerate().map(|(k, img)| {
        (
            (k % columns) as u32 * cell_w + (cell_w - img.width) / 2,
            (k / columns) as u32 * cell_h + (cell_h - img.height) / 2,
        )
    });
    compose(
        images,
        at,
        cell_w * columns as u32,
        cell_h * rows as u32,
        background,
    )
}

/// A `w` x `h` image of `background` with each image copied at its top-left corner.
fn compose(
    images: &[Image],
    at: impl Iterator<Item = (u32, u32)>,
    w: u32,
    h: u32,
    background: [u8; 3],
) -> Image {
    let mut rgb: Vec<u8> = background
        .iter()
        .copied()
        .cycle()
        .take((w * h * 3) as usize)
        .collect();
    for (img, (ox, oy)) in images.iter().zip(at) {
        for y in 0..img.height {
            let src = (y * img.width * 3) as usize;
            let dst = (((oy + y) * w + ox) * 3) as usize;
            rgb[dst..dst + (img.width * 3) as usize]
                .copy_from_slice(&img.rgb[src..src + (img.width * 3) as usize]);
        }
    }
    Image {
        width: w,
        height: h,
        rgb,
    }
}

/// Encodes an image as PNG bytes.
pub fn encode_png(img: &Image) -> Result<Vec<u8>, RenderError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, img.width, img.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::High);
        let mut w = enc.write_header()?;
        w.write_image_data(&img.rgb)?;
    }
    Ok(out)
}

/// Renders and encodes in one go.
pub fn render_png(layers: &[Layer<'_>], opts: &RenderOptions) -> Result<Vec<u8>, RenderError> {
    encode_png(&render(layers, opts)?)
}

/// The error colour map: `t` in 0 to 1 (clamped) from dark blue through cyan, green and
/// yellow to red, piecewise linear through five colours of even lightness steps.
pub fn error_colour(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [40.0, 60.0, 160.0],
        [30.0, 170.0, 210.0],
        [90.0, 190.0, 90.0],
        [240.0, 210.0, 50.0],
        [210.0, 40.0, 30.0],
    ];
    let t = if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) };
    let x = t * (STOPS.len() - 1) as f32;
    let k = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - k as f32;
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    [0, 1, 2].map(|i| (a[i] + (b[i] - a[i]) * f).round() as u8)
}

/// Stacks images top to bottom, each centred horizontally, on a background colour.
pub fn stack(images: &[Image], background: [u8; 3]) -> Image {
    let w = images.iter().map(|i| i.width).max().unwrap_or(1);
    let h = images.iter().map(|i| i.height).sum::<u32>().max(1);
    let mut oy = 0;
    let at: Vec<(u32, u32)> = images
        .iter()
        .map(|img| {
            let p = ((w - img.width) / 2, oy);
            oy += img.height;
            p
        })
        .collect();
    compose(images, at.into_iter(), w, h, background)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(z: f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        (
            vec![
                Vec3::new(-1.0, -1.0, z),
                Vec3::new(1.0, -1.0, z),
                Vec3::new(1.0, 1.0, z),
                Vec3::new(-1.0, 1.0, z),
            ],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn nearer_layer_wins_and_background_stays() {
        let (v_far, t) = quad(0.0);
        let v_near: Vec<Vec3> = v_far
            .iter()
            .map(|p| Vec3::new(p.x * 0.5, p.y * 0.5, 1.0))
            .collect();
        let opts = RenderOptions {
            views: vec![View::Front],
            height: 100,
            margin: 0.1,
            background: [0, 0, 0],
        };
        let img = render(
            &[
                Layer::new(&v_far, &t, [255, 0, 0]),
                Layer::new(&v_near, &t, [0, 255, 0]),
            ],
            &opts,
        )
        .unwrap();
        let px = |x: u32, y: u32| {
            let k = ((y * img.width + x) * 3) as usize;
            [img.rgb[k], img.rgb[k + 1], img.rgb[k + 2]]
        };
        let (cx, cy) = (img.width / 2, img.height / 2);
        assert!(
            px(cx, cy)[1] > 150 && px(cx, cy)[0] == 0,
            "centre is the near green quad"
        );
        assert!(
            px(img.width / 8 + 2, cy)[0] > 150,
            "left edge region is the far red quad"
        );
        assert_eq!(px(0, 0), [0, 0, 0], "corner is background");
        let png = encode_png(&img).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }

    #[test]
    fn empty_input_is_an_error() {
        assert!(render(&[], &RenderOptions::default()).is_err());
    }
}

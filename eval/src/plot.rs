//! Line charts as images (the report's average-precision curves): axes with ticks and
//! numbers, light grid lines, one polyline per series and a legend. Text uses the 8x8
//! bitmap font of the `font8x8` crate (basic Latin).

use crate::render::Image;

/// One line of a chart.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// Points `(x, y)`, drawn in order.
    pub points: Vec<(f64, f64)>,
    /// Line colour (sRGB).
    pub colour: [u8; 3],
}

/// A chart to draw.
#[derive(Debug, Clone)]
pub struct Chart {
    /// Title above the plot.
    pub title: String,
    /// Label under the x axis.
    pub x_label: String,
    /// Label left of the y axis (drawn above the axis, horizontally).
    pub y_label: String,
    /// Axis ranges `(min, max)`.
    pub x_range: (f64, f64),
    /// Axis ranges `(min, max)`.
    pub y_range: (f64, f64),
    /// The lines.
    pub series: Vec<Series>,
}

/// Distinct colours for up to eight series (then they repeat).
pub const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [255, 127, 14],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
];

struct Canvas {
    w: i64,
    h: i64,
    rgb: Vec<u8>,
}

impl Canvas {
    fn new(w: u32, h: u32) -> Self {
        Self {
            w: w as i64,
            h: h as i64,
            rgb: vec![255; (w * h * 3) as usize],
        }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && x < self.w && y < self.h {
            let k = ((y * self.w + x) * 3) as usize;
            self.rgb[k..k + 3].copy_from_slice(&c);
        }
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        for y in y0.min(y1)..=y0.max(y1) {
            for x in x0.min(x1)..=x0.max(x1) {
                self.set(x, y, c);
            }
        }
    }

    /// A line `thickness` pixels wide (square brush), by stepping along the longer axis.
    fn line(&mut self, a: (f64, f64), b: (f64, f64), thickness: i64, c: [u8; 3]) {
        let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as i64).max(1);
        let r0 = -(thickness - 1) / 2;
        for s in 0..=steps {
            let t = s as f64 / steps as f64;
            let x = (a.0 + (b.0 - a.0) * t).round() as i64;
            let y = (a.1 + (b.1 - a.1) * t).round() as i64;
            self.rect(
                x + r0,
                y + r0,
                x + r0 + thickness - 1,
                y + r0 + thickness - 1,
                c,
            );
        }
    }

    /// Text with its top-left corner at `(x, y)`, each font pixel `scale` pixels.
    fn text(&mut self, x: i64, y: i64, s: &str, scale: i64, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let code = ch as usize;
            let glyph = if code < 128 {
                font8x8::legacy::BASIC_LEGACY[code]
            } else {
                font8x8::legacy::BASIC_LEGACY[b'?' as usize]
            };
            let gx = x + k as i64 * 8 * scale;
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits >> col & 1 == 1 {
                        let (px, py) = (gx + col * scale, y + row as i64 * scale);
                        self.rect(px, py, px + scale - 1, py + scale - 1, c);
                    }
                }
            }
        }
    }
}

/// Width of `s` in pixels at `scale`.
fn text_width(s: &str, scale: i64) -> i64 {
    s.chars().count() as i64 * 8 * scale
}

/// About `n` round tick values covering `(lo, hi)`.
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let span = (hi - lo).abs().max(1e-12);
    let raw = span / n.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// `v` with as many decimals as `step` needs (0.25 -> 2, 2.5 -> 1, 5 -> 0).
fn tick_label(v: f64, step: f64) -> String {
    let decimals = (0..6)
        .find(|&d| {
            let s = step * 10f64.powi(d);
            (s - s.round()).abs() < 1e-6 * s.abs().max(1.0)
        })
        .unwrap_or(6) as usize;
    format!("{v:.decimals$}")
}

/// Draws `chart` into a `width` x `height` image.
pub fn line_chart(chart: &Chart, width: u32, height: u32) -> Image {
    let (width, height) = (width.max(200), height.max(150));
    let mut c = Canvas::new(width, height);
    let (black, grey, light) = ([0, 0, 0], [90, 90, 90], [225, 225, 225]);
    let (left, right, top, bottom) = (70i64, 20i64, 44i64, 56i64);
    let (pw, ph) = (c.w - left - right, c.h - top - bottom);
    let (x0, x1) = chart.x_range;
    let (y0, y1) = chart.y_range;
    let sx = |x: f64| left as f64 + (x - x0) / (x1 - x0).max(1e-12) * pw as f64;
    let sy = |y: f64| (top + ph) as f64 - (y - y0) / (y1 - y0).max(1e-12) * ph as f64;
    // Grid and ticks.
    let xt = ticks(x0, x1, 9);
    let yt = ticks(y0, y1, 6);
    let xstep = if xt.len() > 1 { xt[1] - xt[0] } else { 1.0 };
    let ystep = if yt.len() > 1 { yt[1] - yt[0] } else { 1.0 };
    for &x in &xt {
        let px = sx(x).round() as i64;
        c.rect(px, top, px, top + ph, light);
        c.rect(px, top + ph, px, top + ph + 5, black);
        let l = tick_label(x, xstep);
        c.text(px - text_width(&l, 1) / 2, top + ph + 9, &l, 1, grey);
    }
    for &y in &yt {
        let py = sy(y).round() as i64;
        c.rect(left, py, left + pw, py, light);
        c.rect(left - 5, py, left, py, black);
        let l = tick_label(y, ystep);
        c.text(left - 9 - text_width(&l, 1), py - 4, &l, 1, grey);
    }
    // Axes.
    c.rect(left, top, left, top + ph, black);
    c.rect(left, top + ph, left + pw, top + ph, black);
    // Series, clipped to the plot area by clamping (curves here stay inside their ranges).
    for s in &chart.series {
        for w in s.points.windows(2) {
            let a = (sx(w[0].0), sy(w[0].1.clamp(y0, y1)));
            let b = (sx(w[1].0), sy(w[1].1.clamp(y0, y1)));
            c.line(a, b, 2, s.colour);
        }
    }
    // Labels.
    c.text(
        (c.w - text_width(&chart.title, 2)) / 2,
        10,
        &chart.title,
        2,
        black,
    );
    c.text(
        left + (pw - text_width(&chart.x_label, 1)) / 2,
        c.h - 22,
        &chart.x_label,
        1,
        black,
    );
    c.text(8, top - 14, &chart.y_label, 1, black);
    // Legend.
    let lw = chart
        .series
        .iter()
        .map(|s| text_width(&s.label, 1))
        .max()
        .unwrap_or(0)
        + 40;
    let lh = chart.series.len() as i64 * 14 + 8;
    // The corner of the plot area that the fewest points of the series fall into.
    let corners = [
        (left + pw - lw - 10, top + ph - lh - 10),
        (left + 10, top + 10),
        (left + pw - lw - 10, top + 10),
        (left + 10, top + ph - lh - 10),
    ];
    let covered = |&(x, y): &(i64, i64)| {
        chart
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| {
                let (px, py) = (sx(p.0), sy(p.1));
                px >= x as f64 && px <= (x + lw) as f64 && py >= y as f64 && py <= (y + lh) as f64
            })
            .count()
    };
    let (lx, ly) = *corners.iter().min_by_key(|c| covered(c)).expect("corners");
    if !chart.series.is_empty() {
        c.rect(lx, ly, lx + lw, ly + lh, [250, 250, 250]);
        for (k, s) in chart.series.iter().enumerate() {
            let y = ly + 6 + k as i64 * 14;
            c.rect(lx + 6, y + 3, lx + 26, y + 4, s.colour);
            c.text(lx + 32, y, &s.label, 1, black);
        }
    }
    Image {
        width,
        height,
        rgb: c.rgb,
    }
}

/// A horizontal colour bar of [`crate::render::error_colour`] from 0 to `max`, with ticks
/// and a label, `width` pixels wide.
pub fn colour_bar(max: f64, label: &str, width: u32) -> Image {
    let width = width.max(160);
    let mut c = Canvas::new(width, 52);
    let (left, right) = (20i64, 20i64);
    let bw = c.w - left - right;
    for x in 0..bw {
        let col = crate::render::error_colour(x as f32 / (bw - 1).max(1) as f32);
        c.rect(left + x, 18, left + x, 30, col);
    }
    let t = ticks(0.0, max, 6);
    let step = if t.len() > 1 { t[1] - t[0] } else { 1.0 };
    for v in t {
        let px = left + (v / max.max(1e-12) * (bw - 1) as f64).round() as i64;
        c.rect(px, 30, px, 34, [0, 0, 0]);
        let l = tick_label(v, step);
        c.text(px - text_width(&l, 1) / 2, 38, &l, 1, [60, 60, 60]);
    }
    c.text((c.w - text_width(label, 1)) / 2, 4, label, 1, [0, 0, 0]);
    Image {
        width,
        height: 52,
        rgb: c.rgb,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_keep_the_step_s_decimals() {
        assert_eq!(tick_label(0.75, 0.25), "0.75");
        assert_eq!(tick_label(7.5, 2.5), "7.5");
        assert_eq!(tick_label(40.0, 5.0), "40");
        assert_eq!(tick_label(0.6000000000000001, 0.2), "0.6");
    }

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 3.0, 6), vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]);
        assert_eq!(
            ticks(0.0, 45.0, 9),
            vec![0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 45.0]
        );
        assert_eq!(
            ticks(0.0, 1.0, 6),
            vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
        );
    }

    #[test]
    fn a_chart_draws_its_lines_where_the_axes_say() {
        let chart = Chart {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            x_range: (0.0, 1.0),
            y_range: (0.0, 1.0),
            series: vec![Series {
                label: "diagonal".into(),
                points: vec![(0.0, 0.0), (1.0, 1.0)],
                colour: [255, 0, 0],
            }],
        };
        let img = line_chart(&chart, 400, 300);
        assert_eq!((img.width, img.height), (400, 300));
        let px = |x: u32, y: u32| {
            let k = ((y * img.width + x) * 3) as usize;
            [img.rgb[k], img.rgb[k + 1], img.rgb[k + 2]]
        };
        // The plot area is x 70..380, y 44..244: the middle of the diagonal is red.
        assert_eq!(px(225, 144), [255, 0, 0]);
        // Far from the line, inside the plot: not red.
        assert_ne!(px(100, 230), [255, 0, 0]);
    }
}

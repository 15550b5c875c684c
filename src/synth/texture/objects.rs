//! Atlas designs for objects: furniture (a guillotine-split patchwork of
//! wooden fronts, drawers with handles, book rows and labels) and occluders
//! (fabric-like stripes, plaid and blotches). Box faces map to random
//! sub-rectangles of these atlases.

use super::paint::stains;
use super::{fbm, Canvas, Rect, SplitMix64};

/// Paints the furniture atlas.
pub(super) fn furniture(c: &mut Canvas, rng: &mut SplitMix64) {
    let (w, h) = c.size_m();
    c.fill_with(|_, _| 35.0);
    let mut cells = Vec::new();
    split(Rect::new(0.0, 0.0, w, h), rng, &mut cells, 0);
    for cell in cells {
        let r = cell.inset(0.004);
        match rng.below(6) {
            0 => books(c, r, rng),
            1 => {
                // Painted panel with a label.
                let v = rng.range(60.0, 220.0);
                let s = rng.next_u64();
                c.paint_rect(r, move |x, y, _| v + 12.0 * fbm(s, x, y, 0.08, 3, 0.5));
                label(c, r, rng);
            }
            _ => {
                wood(c, r, rng);
                if r.w() > 0.12 && r.h() > 0.08 && rng.chance(0.7) {
                    handle(c, r, rng);
                }
            }
        }
    }
    stains(c, rng, 10.0);
}

/// Recursively splits `r` into cells between ~0.12 and ~0.7 m.
fn split(r: Rect, rng: &mut SplitMix64, out: &mut Vec<Rect>, depth: u32) {
    let big = r.w().max(r.h());
    if depth > 12 || big < 0.25 || (big < 0.7 && rng.chance(0.35)) {
        out.push(r);
        return;
    }
    let t = rng.range(0.3, 0.7);
    if r.w() >= r.h() {
        let x = r.x0 + r.w() * t;
        split(Rect { x1: x, ..r }, rng, out, depth + 1);
        split(Rect { x0: x, ..r }, rng, out, depth + 1);
    } else {
        let y = r.y0 + r.h() * t;
        split(Rect { y1: y, ..r }, rng, out, depth + 1);
        split(Rect { y0: y, ..r }, rng, out, depth + 1);
    }
}

/// Wood with grain along the cell's long side and a bevelled edge.
fn wood(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    let v = rng.range(70.0, 190.0);
    let s = rng.next_u64();
    let along_x = r.w() >= r.h();
    c.paint_rect(r, move |x, y, _| {
        let (a, b) = if along_x { (x, y) } else { (y, x) };
        v + 22.0 * fbm(s, a * 0.12, b, 0.018, 4, 0.6) + 10.0 * fbm(s ^ 2, a, b, 0.3, 2, 0.5)
    });
    c.fill_rect(
        Rect {
            y1: r.y0 + 0.008,
            ..r
        },
        v + 40.0,
    );
    c.fill_rect(
        Rect {
            y0: r.y1 - 0.008,
            ..r
        },
        v - 50.0,
    );
}

/// A bar or knob handle near the top or center of a front.
fn handle(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    let (cx, cy) = (r.x0 + r.w() * 0.5, r.y0 + r.h() * rng.range(0.2, 0.5));
    let dark = rng.chance(0.5);
    let v = if dark { 30.0 } else { 225.0 };
    if rng.chance(0.6) {
        let len = (r.w() * 0.4).min(0.18);
        c.fill_rect(Rect::new(cx - len * 0.5, cy - 0.012, len, 0.024), v);
        c.fill_rect(Rect::new(cx - len * 0.5, cy + 0.008, len, 0.006), 110.0);
    } else {
        c.disk(cx, cy, 0.022, v);
        c.disk(cx - 0.005, cy - 0.005, 0.008, 255.0 - v);
    }
}

/// A row of book spines of random widths and shades, with title bands.
fn books(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    c.fill_rect(r, 40.0);
    let mut x = r.x0;
    while x < r.x1 {
        let bw = rng.range(0.02, 0.06).min(r.x1 - x);
        let top = r.y0 + r.h() * rng.range(0.0, 0.25);
        let spine = Rect::new(x, top, bw, r.y1 - top);
        let v = rng.range(30.0, 230.0);
        c.fill_rect(spine, v);
        let band = top + (r.y1 - top) * rng.range(0.1, 0.3);
        c.fill_rect(Rect::new(x + 0.003, band, bw - 0.006, 0.02), 255.0 - v);
        x += bw + 0.002;
    }
}

/// A light label with dark text blocks.
fn label(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    let lw = (r.w() * 0.5).min(0.15);
    let lh = (r.h() * 0.3).min(0.06);
    let l = Rect::new(r.x0 + (r.w() - lw) * 0.5, r.y0 + r.h() * 0.2, lw, lh);
    c.fill_rect(l, 240.0);
    c.frame(l, 0.003, 90.0);
    c.fill_rect(
        Rect::new(
            l.x0 + 0.01,
            l.y0 + lh * 0.35,
            lw * rng.range(0.3, 0.8),
            lh * 0.3,
        ),
        40.0,
    );
}

/// Paints the occluder atlas: fabric regions (stripes, plaid) and blotches.
pub(super) fn occluder(c: &mut Canvas, rng: &mut SplitMix64) {
    let (w, h) = c.size_m();
    let s = rng.next_u64();
    c.fill_with(|x, y| 110.0 + 50.0 * fbm(s, x, y, 0.3, 4, 0.6));
    let mut cells = Vec::new();
    split(Rect::new(0.0, 0.0, w, h), rng, &mut cells, 0);
    for cell in cells {
        let stripes_a = Stripes::random(rng);
        let plaid = rng.chance(0.4).then(|| Stripes::random(rng));
        let base = rng.range(40.0, 200.0);
        c.paint_rect(cell, move |x, y, _| {
            let mut v = base + stripes_a.at(x, y);
            if let Some(p) = &plaid {
                v += 0.7 * p.at(y, x);
            }
            v
        });
    }
    for _ in 0..(w * h * 6.0) as usize {
        let (x, y) = (rng.range(0.0, w), rng.range(0.0, h));
        c.disk(x, y, rng.range(0.01, 0.06), rng.range(10.0, 245.0));
    }
}

/// Non-periodic stripes along a random direction: boundaries at random
/// spacing, each band with its own random offset.
#[derive(Debug, Clone)]
struct Stripes {
    dir: [f64; 2],
    edges: Vec<f64>,
    levels: Vec<f64>,
}

impl Stripes {
    fn random(rng: &mut SplitMix64) -> Self {
        // A random unit direction without trigonometry.
        let (mut dx, mut dy) = (1.0, 0.0);
        for _ in 0..16 {
            let (a, b) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            let n = (a * a + b * b).sqrt();
            if n > 0.2 && n <= 1.0 {
                (dx, dy) = (a / n, b / n);
                break;
            }
        }
        let mut edges = vec![-6.0];
        let mut levels = vec![0.0];
        while *edges.last().unwrap_or(&6.0) < 6.0 {
            let last = *edges.last().unwrap_or(&6.0);
            edges.push(last + rng.range(0.015, 0.12));
            levels.push(rng.range(-60.0, 60.0));
        }
        Self {
            dir: [dx, dy],
            edges,
            levels,
        }
    }

    fn at(&self, x: f64, y: f64) -> f64 {
        let t = x * self.dir[0] + y * self.dir[1];
        let i = self.edges.partition_point(|&e| e <= t);
        self.levels.get(i.saturating_sub(1)).copied().unwrap_or(0.0)
    }
}

//! Surface designs: dispatch by [`SurfaceKind`], and the floor (planks or
//! tiles) and ceiling (suspended panels) designs. Walls are in `wall.rs`,
//! furniture and occluders in `objects.rs`.
//!
//! Every design mixes gradients at several scales (fBm from ~1 m down to a
//! few texels) with sharp anti-aliased edges at random, non-periodic
//! positions, so a semi-dense direct tracker finds edges in any view.

use super::{fbm, mix64, Canvas, Rect, SplitMix64, SurfaceKind};
use crate::map::GrayTexture;

/// Paints the texture of a `width_m x height_m` surface of `kind` at about
/// `px_per_m` texels per meter. Texture `x` runs along the surface's first
/// axis, `y` down its second (for walls, `y = 0` is the ceiling edge and
/// `y = height_m` the floor). Deterministic in `seed`.
pub fn paint_surface(
    kind: SurfaceKind,
    width_m: f64,
    height_m: f64,
    px_per_m: f64,
    seed: u64,
) -> GrayTexture {
    let mut canvas = Canvas::new(width_m, height_m, px_per_m);
    let mut rng = SplitMix64::new(mix64(seed));
    match kind {
        SurfaceKind::Floor => {
            if rng.chance(0.5) {
                planks(&mut canvas, &mut rng);
            } else {
                tiles(&mut canvas, &mut rng);
            }
        }
        SurfaceKind::Wall => super::wall::wall(&mut canvas, &mut rng),
        SurfaceKind::Ceiling => ceiling(&mut canvas, &mut rng),
        SurfaceKind::Furniture => super::objects::furniture(&mut canvas, &mut rng),
        SurfaceKind::Occluder => super::objects::occluder(&mut canvas, &mut rng),
    }
    canvas.into_texture()
}

/// Maps a rectangle given in (along, across) coordinates to the canvas.
fn orient(r: Rect, swap: bool) -> Rect {
    if swap {
        Rect {
            x0: r.y0,
            y0: r.x0,
            x1: r.y1,
            y1: r.x1,
        }
    } else {
        r
    }
}

/// Wooden planks in staggered rows, with grain, knots and dark joints.
fn planks(c: &mut Canvas, rng: &mut SplitMix64) {
    let (w, h) = c.size_m();
    let swap = rng.chance(0.5);
    let (along, across) = if swap { (h, w) } else { (w, h) };
    let joint = rng.range(40.0, 60.0);
    c.fill_with(|_, _| joint);
    let plank_w = rng.range(0.13, 0.21);
    let gap = rng.range(0.003, 0.006);
    let mut y = -rng.range(0.0, plank_w);
    while y < across {
        let mut x = -rng.range(0.0, 1.6);
        while x < along {
            let len = rng.range(0.6, 1.9);
            let base = rng.range(85.0, 175.0);
            let grain_seed = rng.next_u64();
            let r = Rect::new(x, y, len, plank_w).inset(gap * 0.5);
            let (x0, y0) = (r.x0, r.y0);
            c.paint_rect(orient(r, swap), move |px, py, _| {
                let (a, b) = if swap { (py, px) } else { (px, py) };
                let (a, b) = (a - x0, b - y0);
                base + 24.0 * fbm(grain_seed, a * 0.1, b, 0.02, 4, 0.6)
                    + 12.0 * fbm(grain_seed ^ 1, a, b, 0.35, 2, 0.5)
            });
            for _ in 0..rng.below(3) {
                if rng.chance(0.5) {
                    let kx = x + rng.range(0.05, len - 0.05);
                    let ky = y + rng.range(0.3, 0.7) * plank_w;
                    let r = rng.range(0.008, 0.02);
                    let (cx, cy) = if swap { (ky, kx) } else { (kx, ky) };
                    c.disk(cx, cy, r * 1.6, base - 25.0);
                    c.disk(cx, cy, r, base - 55.0);
                }
            }
            x += len;
        }
        y += plank_w;
    }
    stains(c, rng, 18.0);
}

/// Square or rectangular tiles (optionally staggered) with marbled
/// surfaces, veins and grout lines.
fn tiles(c: &mut Canvas, rng: &mut SplitMix64) {
    let (w, h) = c.size_m();
    let tile_w = rng.range(0.3, 0.6);
    let tile_h = if rng.chance(0.6) {
        tile_w
    } else {
        rng.range(0.3, 0.6)
    };
    let grout = rng.range(0.006, 0.012);
    let grout_value = if rng.chance(0.5) {
        rng.range(40.0, 70.0)
    } else {
        rng.range(200.0, 230.0)
    };
    let stagger = rng.chance(0.4);
    let grout_seed = rng.next_u64();
    c.fill_with(|x, y| grout_value + 10.0 * fbm(grout_seed, x, y, 0.1, 2, 0.5));
    let (ox, oy) = (rng.range(0.0, tile_w), rng.range(0.0, tile_h));
    let mut row = 0usize;
    let mut y = -oy;
    while y < h {
        let shift = if stagger && row % 2 == 1 {
            tile_w * 0.5
        } else {
            0.0
        };
        let mut x = -ox - shift;
        while x < w {
            let base = rng.range(75.0, 195.0);
            let s = rng.next_u64();
            let vein = rng.range(25.0, 60.0);
            let r = Rect::new(x, y, tile_w, tile_h).inset(grout * 0.5);
            c.paint_rect(r, move |px, py, _| {
                let n = fbm(s ^ 7, px, py, 0.25, 4, 0.55);
                let line = (1.0 - (n.abs() * 10.0)).max(0.0);
                base + 22.0 * fbm(s, px, py, 0.12, 5, 0.6) - vein * line
            });
            x += tile_w;
        }
        y += tile_h;
        row += 1;
    }
    stains(c, rng, 14.0);
}

/// Suspended ceiling: a panel grid with metal bars and shadows, speckled
/// panels, some light fixtures with louvres, vents and detectors.
fn ceiling(c: &mut Canvas, rng: &mut SplitMix64) {
    let (w, h) = c.size_m();
    let panel = rng.range(0.55, 0.65);
    let bar = rng.range(0.018, 0.028);
    let bar_value = rng.range(215.0, 240.0);
    let (ox, oy) = (rng.range(0.0, panel), rng.range(0.0, panel));
    let nx = ((w + ox) / panel).ceil() as i64 + 1;
    let ny = ((h + oy) / panel).ceil() as i64 + 1;
    let low = rng.next_u64();
    // Fissures about 1.5 texels wide.
    let fissure_k = 0.08 * c.px_per_m / 1.5;
    c.fill_with(|x, y| 180.0 + 15.0 * fbm(low, x, y, 1.5, 2, 0.5));
    for j in 0..ny {
        for i in 0..nx {
            let r = Rect::new(i as f64 * panel - ox, j as f64 * panel - oy, panel, panel);
            let inner = r.inset(bar * 0.5);
            let roll = rng.next_f64();
            let s = rng.next_u64();
            if roll < 0.1 {
                light_fixture(c, inner, rng);
            } else if roll < 0.15 {
                // Vent: concentric squares.
                c.fill_rect(inner, 200.0);
                let mut k = 0;
                let mut q = inner.inset(0.05);
                while q.w() > 0.04 {
                    c.fill_rect(q, if k % 2 == 0 { 95.0 } else { 200.0 });
                    q = q.inset(rng.range(0.02, 0.035));
                    k += 1;
                }
            } else {
                let base = rng.range(150.0, 215.0);
                c.paint_rect(inner, move |x, y, old| {
                    // Speckle plus dark worm-like fissures of acoustic tiles.
                    let fissure = (1.0 - fbm(s ^ 5, x, y, 0.08, 2, 0.5).abs() * fissure_k).max(0.0);
                    0.3 * old
                        + 0.7 * base
                        + 14.0 * fbm(s, x, y, 0.035, 2, 0.5)
                        + 9.0 * fbm(s ^ 3, x, y, 0.25, 2, 0.5)
                        - 45.0 * fissure
                });
                // Shadow of the bar on one side of the panel.
                c.fill_rect(
                    Rect {
                        y1: inner.y0 + 0.012,
                        ..inner
                    },
                    base - 45.0,
                );
                c.fill_rect(
                    Rect {
                        x1: inner.x0 + 0.012,
                        ..inner
                    },
                    base - 35.0,
                );
                if rng.chance(0.06) {
                    let (cx, cy) = (inner.x0 + inner.w() * 0.5, inner.y0 + inner.h() * 0.5);
                    c.disk(cx, cy, 0.065, 120.0);
                    c.disk(cx, cy, 0.05, 240.0);
                    c.disk(cx, cy, 0.012, 60.0);
                }
            }
        }
    }
    for j in 0..ny {
        let y = j as f64 * panel - oy;
        c.fill_rect(Rect::new(0.0, y - bar * 0.5, w, bar), bar_value);
    }
    for i in 0..nx {
        let x = i as f64 * panel - ox;
        c.fill_rect(Rect::new(x - bar * 0.5, 0.0, bar, h), bar_value);
    }
}

/// A bright fixture with a dark rim and irregularly spaced louvres.
fn light_fixture(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    c.fill_rect(r, 120.0);
    let lamp = r.inset(0.02);
    c.fill_rect(lamp, 250.0);
    let vertical = rng.chance(0.5);
    let mut t = 0.03;
    let span = if vertical { lamp.w() } else { lamp.h() };
    while t < span - 0.02 {
        let line = if vertical {
            Rect::new(lamp.x0 + t, lamp.y0, 0.008, lamp.h())
        } else {
            Rect::new(lamp.x0, lamp.y0 + t, lamp.w(), 0.008)
        };
        c.fill_rect(line, 175.0);
        t += rng.range(0.05, 0.1);
    }
}

/// Low-contrast irregular blotches (dirt, wear) over the whole canvas.
pub(super) fn stains(c: &mut Canvas, rng: &mut SplitMix64, amplitude: f64) {
    let s = rng.next_u64();
    let (w, h) = c.size_m();
    c.paint_rect(Rect::new(0.0, 0.0, w, h), move |x, y, old| {
        let n = fbm(s, x, y, 0.8, 3, 0.5);
        old + amplitude * (n - 0.15).max(0.0) * -2.5
            + 0.3 * amplitude * fbm(s ^ 5, x, y, 0.07, 2, 0.5)
    });
}

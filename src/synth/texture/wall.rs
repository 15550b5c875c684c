//! The wall design: noisy paint, a skirting board, maybe a door, switches
//! and sockets, small marks, and framed posters, notices and charts placed
//! without overlap. Texture `y = 0` is the ceiling edge, `y = height` the
//! floor.

use super::paint::stains;
use super::{fbm, Canvas, Rect, SplitMix64};

/// Paints a wall.
pub(super) fn wall(c: &mut Canvas, rng: &mut SplitMix64) {
    let (w, h) = c.size_m();
    let base = rng.range(150.0, 200.0);
    let (s1, s2, s3, s4) = (
        rng.next_u64(),
        rng.next_u64(),
        rng.next_u64(),
        rng.next_u64(),
    );
    let blotch = rng.range(22.0, 32.0);
    let blob_m = rng.range(0.04, 0.07);
    // Steepness so that blob edges span about 1.5 texels and cracks are
    // 1.5 texels wide: sharp but anti-aliased (fBm slopes are about
    // 2 / wavelength).
    let texel_m = 1.0 / c.px_per_m;
    let blob_k = blob_m / (3.0 * texel_m);
    let crack_k = 0.35 / (1.5 * texel_m);
    c.fill_with(|x, y| {
        // Broad shading, "knockdown" plaster blobs with crisp edges, fine
        // grain, and hairline cracks in a few areas.
        let blob = ((fbm(s2, x, y, blob_m, 2, 0.5) - 0.1) * blob_k).clamp(0.0, 1.0);
        let crack_area = ((fbm(s4 ^ 1, x, y, 1.5, 2, 0.5) - 0.25) * 6.0).clamp(0.0, 1.0);
        let crack = (1.0 - fbm(s4, x, y, 0.35, 3, 0.5).abs() * crack_k).max(0.0);
        base + 20.0 * fbm(s1, x, y, 1.3, 3, 0.5) - blotch * blob
            + 6.0 * fbm(s3, x, y, 0.025, 2, 0.5)
            - 40.0 * crack * crack_area
    });
    marks(c, rng, w * h * 12.0, base);
    stains(c, rng, 12.0);

    let mut occupied: Vec<Rect> = Vec::new();
    // Skirting board along the floor.
    let skirting = rng.range(0.07, 0.12);
    let board = Rect::new(0.0, h - skirting, w, skirting);
    let board_value = if rng.chance(0.5) { base - 80.0 } else { 235.0 };
    let sb = rng.next_u64();
    c.paint_rect(board, move |x, y, _| {
        board_value + 8.0 * fbm(sb, x, y, 0.2, 2, 0.5)
    });
    c.fill_rect(Rect::new(0.0, h - skirting, w, 0.008), board_value - 45.0);
    occupied.push(board);

    if w > 2.0 && h > 2.4 && rng.chance(0.6) {
        let door = door(c, rng, base);
        occupied.push(door.inset(-0.15));
        // Light switch beside the door.
        let sx = if door.x0 > 0.3 {
            door.x0 - 0.2
        } else {
            door.x1 + 0.12
        };
        let switch = Rect::new(sx, h - 1.15, 0.08, 0.12);
        c.fill_rect(switch, 228.0);
        c.frame(switch, 0.006, 140.0);
        c.fill_rect(switch.inset(0.028), 205.0);
        occupied.push(switch);
    }
    for _ in 0..(1 + rng.below(4)) {
        let socket = Rect::new(rng.range(0.1, (w - 0.2).max(0.11)), h - 0.38, 0.085, 0.085);
        if occupied.iter().any(|o| o.overlaps(&socket, 0.02)) {
            continue;
        }
        c.fill_rect(socket, 232.0);
        c.frame(socket, 0.005, 130.0);
        let (cx, cy) = (socket.x0 + 0.0425, socket.y0 + 0.0425);
        c.disk(cx - 0.013, cy, 0.007, 40.0);
        c.disk(cx + 0.013, cy, 0.007, 40.0);
        occupied.push(socket);
    }

    let wanted = (w * h / 2.0).round().max(1.0) as usize;
    let mut placed = 0;
    for _ in 0..wanted * 40 {
        if placed >= wanted {
            break;
        }
        let pw = rng.range(0.3, 1.1).min(w - 0.2);
        let ph = rng.range(0.3, 1.2).min(h - 0.9);
        if pw < 0.2 || ph < 0.2 {
            break;
        }
        let x = rng.range(0.1, w - pw - 0.1);
        let y = rng.range(0.25, (h - 0.5 - ph).max(0.26));
        let r = Rect::new(x, y, pw, ph);
        if occupied.iter().any(|o| o.overlaps(&r, 0.1)) {
            continue;
        }
        match rng.below(5) {
            0 | 1 => picture(c, r, rng),
            2 => notice(c, r, rng),
            3 => chart(c, r, rng),
            _ => cork_board(c, r, rng),
        }
        occupied.push(r);
        placed += 1;
    }
}

/// Small marks: scuffs, nail holes, tape remains.
fn marks(c: &mut Canvas, rng: &mut SplitMix64, count: f64, base: f64) {
    let (w, h) = c.size_m();
    for _ in 0..count as usize {
        let (x, y) = (rng.range(0.0, w), rng.range(0.0, h));
        let v = base + rng.range(-45.0, 30.0);
        if rng.chance(0.5) {
            c.disk(x, y, rng.range(0.004, 0.02), v);
        } else {
            c.fill_rect(
                Rect::new(x, y, rng.range(0.01, 0.06), rng.range(0.01, 0.04)),
                v,
            );
        }
    }
}

/// A panelled door with trim and a handle, standing on the floor.
fn door(c: &mut Canvas, rng: &mut SplitMix64, wall_base: f64) -> Rect {
    let (w, h) = c.size_m();
    let dw = rng.range(0.8, 1.0);
    let dh = 2.05f64.min(h - 0.3);
    let r = Rect::new(rng.range(0.3, w - dw - 0.3), h - dh, dw, dh);
    let trim = r.inset(-0.07);
    c.fill_rect(trim, wall_base - 55.0);
    c.fill_rect(
        Rect {
            y1: trim.y0 + 0.01,
            ..trim
        },
        wall_base - 90.0,
    );
    let leaf_value = rng.range(95.0, 160.0);
    let s = rng.next_u64();
    c.paint_rect(r, move |x, y, _| {
        leaf_value + 24.0 * fbm(s, x * 4.0, y * 0.25, 0.05, 3, 0.6)
    });
    let rows = 2 + rng.below(3);
    let cols = 1 + rng.below(2);
    let margin = 0.1;
    let pw = (dw - margin * (cols as f64 + 1.0)) / cols as f64;
    let ph = (dh - margin * (rows as f64 + 1.0)) / rows as f64;
    for j in 0..rows {
        for i in 0..cols {
            let p = Rect::new(
                r.x0 + margin + i as f64 * (pw + margin),
                r.y0 + margin + j as f64 * (ph + margin),
                pw,
                ph,
            );
            // Bevel: light top-left, dark bottom-right.
            c.fill_rect(p, leaf_value + 35.0);
            c.fill_rect(
                Rect::new(p.x0 + 0.015, p.y0 + 0.015, pw - 0.015, ph - 0.015),
                leaf_value - 40.0,
            );
            let (shift, ps) = (rng.range(-15.0, 15.0), rng.next_u64());
            c.paint_rect(p.inset(0.015), move |x, y, _| {
                // Vertical grain, knots of darker wood.
                leaf_value + shift + 24.0 * fbm(ps, x * 4.0, y * 0.25, 0.05, 3, 0.6)
                    - 30.0 * ((fbm(ps ^ 1, x, y, 0.12, 2, 0.5) - 0.35) * 8.0).clamp(0.0, 1.0)
            });
        }
    }
    let (hx, hy) = (r.x1 - 0.09, r.y0 + dh - 1.0);
    c.fill_rect(Rect::new(hx - 0.02, hy - 0.08, 0.04, 0.16), 210.0);
    c.disk(hx, hy, 0.028, 35.0);
    c.fill_rect(Rect::new(hx - 0.12, hy - 0.012, 0.12, 0.024), 45.0);
    r
}

/// A framed picture: frame, optional mat, and an abstract image.
fn picture(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    let frame_value = if rng.chance(0.6) {
        rng.range(20.0, 70.0)
    } else {
        rng.range(200.0, 240.0)
    };
    let t = rng.range(0.015, 0.05);
    c.frame(r, t, frame_value);
    c.fill_rect(
        Rect {
            y0: r.y1 - t * 0.3,
            ..r
        },
        frame_value * 0.6,
    );
    let mut inner = r.inset(t);
    if rng.chance(0.5) {
        c.fill_rect(inner, rng.range(215.0, 245.0));
        inner = inner.inset(rng.range(0.03, 0.08).min(inner.w() * 0.2));
    }
    let (bg, s) = (rng.range(60.0, 190.0), rng.next_u64());
    let contrast = rng.range(40.0, 80.0);
    let horizon = inner.y0 + inner.h() * rng.range(0.3, 0.7);
    let sky = rng.range(-60.0, 60.0);
    c.paint_rect(inner, move |x, y, _| {
        let shift = if y < horizon { sky } else { 0.0 };
        bg + shift + contrast * fbm(s, x, y, 0.25, 4, 0.55)
    });
    for _ in 0..(4 + rng.below(12)) {
        let sw = rng.range(0.03, 0.4).min(inner.w());
        let sh = rng.range(0.03, 0.4).min(inner.h());
        let x = rng.range(inner.x0, inner.x1 - sw);
        let y = rng.range(inner.y0, inner.y1 - sh);
        let v = rng.range(10.0, 245.0);
        if rng.chance(0.5) {
            c.fill_rect(Rect::new(x, y, sw, sh), v);
        } else {
            let rad = 0.5 * sw.min(sh);
            c.disk(x + rad, y + rad, rad, v);
        }
    }
}

/// A notice: paper with a heading and lines of word blocks.
fn notice(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    c.fill_rect(r.inset(-0.004), 90.0);
    c.fill_rect(r, rng.range(220.0, 248.0));
    let ink = rng.range(25.0, 90.0);
    let heading = Rect::new(
        r.x0 + 0.04,
        r.y0 + 0.04,
        (r.w() - 0.08) * rng.range(0.4, 0.9),
        0.05,
    );
    c.fill_rect(heading, ink);
    let spacing = rng.range(0.04, 0.06);
    let mut y = heading.y1 + spacing;
    while y + 0.025 < r.y1 - 0.04 {
        let mut x = r.x0 + 0.04;
        let end = r.x1 - 0.04 - rng.range(0.0, 0.2);
        while x < end {
            let word = rng.range(0.02, 0.1).min(end - x);
            c.fill_rect(Rect::new(x, y, word, 0.022), ink + rng.range(0.0, 40.0));
            x += word + rng.range(0.015, 0.025);
        }
        y += spacing;
        if rng.chance(0.15) {
            y += spacing; // paragraph break
        }
    }
}

/// A bar chart on a whiteboard with an axis and a few grid lines.
fn chart(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    c.frame(r, 0.02, 170.0);
    let inner = r.inset(0.02);
    c.fill_rect(inner, 238.0);
    let plot = inner.inset(0.06);
    let mut y = plot.y0;
    while y < plot.y1 {
        c.fill_rect(Rect::new(plot.x0, y, plot.w(), 0.004), 200.0);
        y += rng.range(0.05, 0.1);
    }
    let bars = 3 + rng.below(6);
    let slot = plot.w() / bars as f64;
    for i in 0..bars {
        let bh = plot.h() * rng.range(0.15, 0.95);
        let b = Rect::new(
            plot.x0 + i as f64 * slot + slot * 0.15,
            plot.y1 - bh,
            slot * 0.7,
            bh,
        );
        c.fill_rect(b, rng.range(30.0, 170.0));
    }
    c.fill_rect(Rect::new(plot.x0, plot.y0, 0.008, plot.h()), 30.0);
    c.fill_rect(Rect::new(plot.x0, plot.y1 - 0.008, plot.w(), 0.008), 30.0);
}

/// A cork board with pinned cards.
fn cork_board(c: &mut Canvas, r: Rect, rng: &mut SplitMix64) {
    c.frame(r, 0.025, rng.range(60.0, 110.0));
    let inner = r.inset(0.025);
    let s = rng.next_u64();
    c.paint_rect(inner, move |x, y, _| {
        125.0 + 30.0 * fbm(s, x, y, 0.015, 2, 0.6) + 10.0 * fbm(s ^ 9, x, y, 0.2, 2, 0.5)
    });
    for _ in 0..(2 + rng.below(8)) {
        let cw = rng.range(0.06, 0.2).min(inner.w() * 0.8);
        let ch = rng.range(0.05, 0.15).min(inner.h() * 0.8);
        let x = rng.range(inner.x0, inner.x1 - cw);
        let y = rng.range(inner.y0, inner.y1 - ch);
        let card = Rect::new(x, y, cw, ch);
        c.fill_rect(card, rng.range(180.0, 250.0));
        c.fill_rect(Rect::new(x + 0.01, y + 0.02, cw * 0.6, 0.012), 60.0);
        c.disk(x + cw * 0.5, y + 0.008, 0.006, rng.range(10.0, 80.0));
    }
}

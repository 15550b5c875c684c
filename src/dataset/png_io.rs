//! PNG decoding and encoding for dataset images.
//!
//! Camera frames are decoded to 8-bit gray: gray PNGs as they are, color
//! PNGs through Rec.601 luma (`Y = 0.299 R + 0.587 G + 0.114 B`), 16-bit
//! channels by their high byte, alpha ignored. Depth PNGs are 16-bit gray.
//! Decoding writes into a caller-provided image and scratch buffer, so a
//! replay loop reuses its allocations.

use std::fs::File;
use std::io::{BufReader, BufWriter};
use std::path::Path;

use image::codecs::png::{CompressionType, FilterType, PngDecoder, PngEncoder};
use image::{ColorType, ExtendedColorType, ImageDecoder, ImageEncoder};

use super::DatasetError;
use crate::imgproc::ImageU8;

/// Rec.601 luma of an 8-bit RGB triple, rounded.
#[inline]
pub fn luma601(r: u8, g: u8, b: u8) -> u8 {
    // Weights scaled by 1000: 299 + 587 + 114 = 1000, so the result is <= 255.
    ((299 * r as u32 + 587 * g as u32 + 114 * b as u32 + 500) / 1000) as u8
}

fn open_decoder(path: &Path) -> Result<PngDecoder<BufReader<File>>, DatasetError> {
    let file = super::open_regular_file(path)?;
    PngDecoder::new(BufReader::new(file)).map_err(|e| DatasetError::Decode {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

fn check_size(
    path: &Path,
    found: (u32, u32),
    want: Option<(u32, u32)>,
) -> Result<(), DatasetError> {
    match want {
        Some(want) if want != found => Err(DatasetError::ImageSize {
            path: path.to_path_buf(),
            found_w: found.0,
            found_h: found.1,
            want_w: want.0,
            want_h: want.1,
        }),
        _ => Ok(()),
    }
}

/// Decodes the PNG at `path` into 8-bit gray `out` (resized in place).
/// `expected_size` (`width, height`) is checked before decoding the pixels.
/// `scratch` holds color pixels before conversion and is reused.
pub fn decode_gray_into(
    path: &Path,
    expected_size: Option<(u32, u32)>,
    out: &mut ImageU8,
    scratch: &mut Vec<u8>,
) -> Result<(), DatasetError> {
    let decoder = open_decoder(path)?;
    let (w, h) = decoder.dimensions();
    check_size(path, (w, h), expected_size)?;
    let color = decoder.color_type();
    let n = w as usize * h as usize;
    out.resize(w as usize, h as usize, 0);
    let decode_err = |e: image::ImageError| DatasetError::Decode {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    if color == ColorType::L8 {
        return decoder.read_image(out.data_mut()).map_err(decode_err);
    }
    scratch.resize(decoder.total_bytes() as usize, 0);
    decoder.read_image(scratch).map_err(decode_err)?;
    let px = out.data_mut();
    // 16-bit samples arrive in native endian; the high byte is the 8-bit value.
    let hi = |s: &[u8], i: usize| (u16::from_ne_bytes([s[2 * i], s[2 * i + 1]]) >> 8) as u8;
    let s = scratch.as_slice();
    match color {
        ColorType::La8 => px
            .iter_mut()
            .zip(s.chunks_exact(2))
            .for_each(|(p, c)| *p = c[0]),
        ColorType::Rgb8 => px
            .iter_mut()
            .zip(s.chunks_exact(3))
            .for_each(|(p, c)| *p = luma601(c[0], c[1], c[2])),
        ColorType::Rgba8 => px
            .iter_mut()
            .zip(s.chunks_exact(4))
            .for_each(|(p, c)| *p = luma601(c[0], c[1], c[2])),
        ColorType::L16 | ColorType::La16 | ColorType::Rgb16 | ColorType::Rgba16 => {
            let channels = color.channel_count() as usize;
            for (i, p) in px.iter_mut().enumerate().take(n) {
                let base = i * channels;
                *p = if channels >= 3 {
                    luma601(hi(s, base), hi(s, base + 1), hi(s, base + 2))
                } else {
                    hi(s, base)
                };
            }
        }
        other => {
            return Err(DatasetError::Decode {
                path: path.to_path_buf(),
                message: format!(
                    "unsupported pixel format {other:?}; expected 8/16-bit gray or RGB(A)"
                ),
            })
        }
    }
    Ok(())
}

/// Decodes a 16-bit gray depth PNG into raw units (row-major).
pub fn decode_u16(
    path: &Path,
    expected_size: Option<(u32, u32)>,
    out: &mut Vec<u16>,
) -> Result<(), DatasetError> {
    let decoder = open_decoder(path)?;
    let (w, h) = decoder.dimensions();
    check_size(path, (w, h), expected_size)?;
    if decoder.color_type() != ColorType::L16 {
        return Err(DatasetError::Decode {
            path: path.to_path_buf(),
            message: format!(
                "depth image is {:?}; expected 16-bit gray (L16)",
                decoder.color_type()
            ),
        });
    }
    let mut bytes = vec![0u8; decoder.total_bytes() as usize];
    decoder
        .read_image(&mut bytes)
        .map_err(|e| DatasetError::Decode {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    out.clear();
    out.extend(
        bytes
            .chunks_exact(2)
            .map(|b| u16::from_ne_bytes([b[0], b[1]])),
    );
    Ok(())
}

fn encode(
    path: &Path,
    bytes: &[u8],
    w: u32,
    h: u32,
    color: ExtendedColorType,
) -> Result<(), DatasetError> {
    let file = File::create(path).map_err(|e| DatasetError::io(path, e))?;
    let encoder = PngEncoder::new_with_quality(
        BufWriter::new(file),
        CompressionType::Fast,
        FilterType::Adaptive,
    );
    encoder
        .write_image(bytes, w, h, color)
        .map_err(|e| DatasetError::Encode {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

/// Writes an 8-bit gray PNG.
pub fn write_gray8(path: &Path, image: &ImageU8) -> Result<(), DatasetError> {
    encode(
        path,
        image.data(),
        image.width() as u32,
        image.height() as u32,
        ExtendedColorType::L8,
    )
}

/// Writes a 16-bit gray PNG from row-major samples (`width * height` of them).
pub fn write_gray16(
    path: &Path,
    width: u32,
    height: u32,
    samples: &[u16],
) -> Result<(), DatasetError> {
    let bytes: Vec<u8> = samples.iter().flat_map(|v| v.to_ne_bytes()).collect();
    encode(path, &bytes, width, height, ExtendedColorType::L16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_weights_are_rec601() {
        assert_eq!(luma601(255, 255, 255), 255);
        assert_eq!(luma601(0, 0, 0), 0);
        assert_eq!(luma601(255, 0, 0), 76);
        assert_eq!(luma601(0, 255, 0), 150);
        assert_eq!(luma601(0, 0, 255), 29);
    }

    #[test]
    fn gray_color_and_16bit_pngs_decode_to_gray() {
        let dir = tempfile::tempdir().expect("tempdir");
        let gray = ImageU8::from_vec(3, 2, vec![0, 50, 100, 150, 200, 255]).expect("3x2");
        let p = dir.path().join("g.png");
        write_gray8(&p, &gray).expect("write");
        let (mut out, mut scratch) = (ImageU8::new(1, 1, 0), Vec::new());
        decode_gray_into(&p, Some((3, 2)), &mut out, &mut scratch).expect("decode");
        assert_eq!(out, gray);

        let rgb = image::RgbImage::from_fn(3, 2, |x, y| {
            image::Rgb([(x * 100) as u8, (y * 200) as u8, 30])
        });
        let p = dir.path().join("c.png");
        rgb.save(&p).expect("save");
        decode_gray_into(&p, None, &mut out, &mut scratch).expect("decode");
        assert_eq!(out.get(2, 1), Some(luma601(200, 200, 30)));

        let p = dir.path().join("d.png");
        write_gray16(&p, 2, 1, &[1000, 65535]).expect("write16");
        let mut depth = Vec::new();
        decode_u16(&p, Some((2, 1)), &mut depth).expect("decode16");
        assert_eq!(depth, vec![1000, 65535]);
        decode_gray_into(&p, None, &mut out, &mut scratch).expect("16-bit gray as 8-bit");
        assert_eq!(out.data(), &[3, 255]);
    }

    #[test]
    fn wrong_size_and_garbage_are_errors() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("g.png");
        write_gray8(&p, &ImageU8::new(4, 3, 7)).expect("write");
        let (mut out, mut scratch) = (ImageU8::new(1, 1, 0), Vec::new());
        let err = decode_gray_into(&p, Some((640, 512)), &mut out, &mut scratch).unwrap_err();
        assert!(matches!(
            err,
            DatasetError::ImageSize {
                found_w: 4,
                found_h: 3,
                want_w: 640,
                ..
            }
        ));
        let bad = dir.path().join("bad.png");
        std::fs::write(&bad, b"not a png at all").expect("write");
        let err = decode_gray_into(&bad, None, &mut out, &mut scratch).unwrap_err();
        assert!(matches!(err, DatasetError::Decode { .. }), "{err}");
        let mut depth = Vec::new();
        assert!(matches!(
            decode_u16(&p, None, &mut depth),
            Err(DatasetError::Decode { .. })
        ));
        let missing = dir.path().join("missing.png");
        assert!(matches!(
            decode_gray_into(&missing, None, &mut out, &mut scratch),
            Err(DatasetError::MissingFile { .. })
        ));
    }
}

//! Pixel conversions from what cameras deliver to tightly packed 8-bit gray:
//! GREY/Y8 (copy rows), YUYV (take Y), MJPG (decode luma with zune-jpeg).
//!
//! Takes in a driver buffer, its row stride and the frame size; writes into a
//! caller-provided slice. GREY and YUYV do not allocate; the JPEG decoder
//! allocates its own scratch per frame.

use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;
use zune_jpeg::JpegDecoder;

/// Why a buffer could not be converted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ConvertError {
    /// The buffer holds fewer bytes than the frame needs.
    #[error("buffer has {found} bytes, frame needs {needed}")]
    Short {
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        found: usize,
    },
    /// The destination is smaller than the frame.
    #[error("destination holds {capacity} bytes, frame needs {needed}")]
    DestinationTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Bytes available.
        capacity: usize,
    },
    /// The JPEG is corrupt or has another size than negotiated.
    #[error("jpeg: {0}")]
    Jpeg(String),
}

fn check(
    src_len: usize,
    src_stride: usize,
    row_bytes: usize,
    height: usize,
    dst_len: usize,
    width: usize,
) -> Result<(), ConvertError> {
    let needed = if height == 0 {
        0
    } else {
        src_stride * (height - 1) + row_bytes
    };
    if src_len < needed || src_stride < row_bytes {
        return Err(ConvertError::Short {
            needed,
            found: src_len,
        });
    }
    if dst_len < width * height {
        return Err(ConvertError::DestinationTooSmall {
            needed: width * height,
            capacity: dst_len,
        });
    }
    Ok(())
}

/// Copies 8-bit gray rows (`src_stride` apart) into packed `dst`.
pub fn gray_from_grey(
    src: &[u8],
    src_stride: usize,
    width: usize,
    height: usize,
    dst: &mut [u8],
) -> Result<(), ConvertError> {
    check(src.len(), src_stride, width, height, dst.len(), width)?;
    for (y, out) in dst.chunks_exact_mut(width).take(height).enumerate() {
        out.copy_from_slice(&src[y * src_stride..y * src_stride + width]);
    }
    Ok(())
}

/// Takes the luma of packed YUYV (Y0 U Y1 V) rows into packed `dst`.
pub fn gray_from_yuyv(
    src: &[u8],
    src_stride: usize,
    width: usize,
    height: usize,
    dst: &mut [u8],
) -> Result<(), ConvertError> {
    check(src.len(), src_stride, 2 * width, height, dst.len(), width)?;
    for (y, out) in dst.chunks_exact_mut(width).take(height).enumerate() {
        let row = &src[y * src_stride..y * src_stride + 2 * width];
        for (o, px) in out.iter_mut().zip(row.chunks_exact(2)) {
            *o = px[0];
        }
    }
    Ok(())
}

/// Decodes a JPEG (one MJPG frame) to luma into packed `dst`; the image must
/// be `width` x `height`.
pub fn gray_from_jpeg(
    src: &[u8],
    width: usize,
    height: usize,
    dst: &mut [u8],
) -> Result<(), ConvertError> {
    if dst.len() < width * height {
        return Err(ConvertError::DestinationTooSmall {
            needed: width * height,
            capacity: dst.len(),
        });
    }
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::Luma);
    let mut decoder = JpegDecoder::new_with_options(ZCursor::new(src), options);
    decoder
        .decode_headers()
        .map_err(|e| ConvertError::Jpeg(e.to_string()))?;
    let (w, h) = decoder
        .dimensions()
        .ok_or_else(|| ConvertError::Jpeg("no dimensions after headers".into()))?;
    if (w, h) != (width, height) {
        return Err(ConvertError::Jpeg(format!(
            "image is {w}x{h}, expected {width}x{height}"
        )));
    }
    decoder
        .decode_into(&mut dst[..width * height])
        .map_err(|e| ConvertError::Jpeg(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_drops_stride_padding() {
        let src = [1, 2, 0, 3, 4, 0];
        let mut dst = [9u8; 4];
        gray_from_grey(&src, 3, 2, 2, &mut dst).expect("fits");
        assert_eq!(dst, [1, 2, 3, 4]);
        assert!(matches!(
            gray_from_grey(&src[..4], 3, 2, 2, &mut dst),
            Err(ConvertError::Short { .. })
        ));
    }

    #[test]
    fn yuyv_takes_luma() {
        let src = [10, 128, 20, 129, 30, 130, 40, 131];
        let mut dst = [0u8; 4];
        gray_from_yuyv(&src, 4, 2, 2, &mut dst).expect("fits");
        assert_eq!(dst, [10, 20, 30, 40]);
        let mut small = [0u8; 3];
        assert!(matches!(
            gray_from_yuyv(&src, 4, 2, 2, &mut small),
            Err(ConvertError::DestinationTooSmall { .. })
        ));
    }

    #[test]
    fn jpeg_decodes_to_luma_and_checks_size() {
        let (w, h) = (32u32, 16u32);
        let gray = image::GrayImage::from_fn(w, h, |x, _| image::Luma([(x * 8) as u8]));
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&gray)
            .expect("encode");
        let mut dst = vec![0u8; (w * h) as usize];
        gray_from_jpeg(&jpeg, w as usize, h as usize, &mut dst).expect("decode");
        let max_err = dst
            .iter()
            .zip(gray.as_raw())
            .map(|(a, b)| (*a as i32 - *b as i32).abs())
            .max()
            .expect("pixels");
        assert!(max_err <= 6, "max error {max_err}");
        assert!(gray_from_jpeg(&jpeg, 16, 16, &mut dst).is_err());
        assert!(gray_from_jpeg(&jpeg[..20], 32, 16, &mut dst).is_err());
    }
}

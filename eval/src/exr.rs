//! Float images as OpenEXR files: one 32-bit float channel `Y`, uncompressed scan lines,
//! written from the layout in the OpenEXR file-format description (magic number, version,
//! header attributes, line offset table, then one block per scan line).

/// Encodes `data` (`width` x `height`, row-major, top row first) as a single-channel EXR.
/// NaN marks pixels without a value; EXR viewers show them as such.
pub fn encode_gray(width: u32, height: u32, data: &[f32]) -> Vec<u8> {
    assert_eq!(data.len(), (width * height) as usize, "image size");
    assert!(width > 0 && height > 0, "empty image");
    let mut out = Vec::new();
    out.extend_from_slice(&[0x76, 0x2f, 0x31, 0x01]); // magic
    out.extend_from_slice(&2u32.to_le_bytes()); // version 2, single-part scan lines
    let mut attr = |name: &str, kind: &str, value: &[u8]| {
        out.extend_from_slice(name.as_bytes());
        out.push(0);
        out.extend_from_slice(kind.as_bytes());
        out.push(0);
        out.extend_from_slice(&(value.len() as u32).to_le_bytes());
        out.extend_from_slice(value);
    };
    // Channel list: name, pixel type 2 (FLOAT), pLinear 0, 3 reserved, x and y sampling 1.
    let mut chlist = b"Y\0".to_vec();
    chlist.extend_from_slice(&2i32.to_le_bytes());
    chlist.extend_from_slice(&[0, 0, 0, 0]);
    chlist.extend_from_slice(&1i32.to_le_bytes());
    chlist.extend_from_slice(&1i32.to_le_bytes());
    chlist.push(0);
    attr("channels", "chlist", &chlist);
    attr("compression", "compression", &[0]); // NO_COMPRESSION
    let window: Vec<u8> = [0i32, 0, width as i32 - 1, height as i32 - 1]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    attr("dataWindow", "box2i", &window);
    attr("displayWindow", "box2i", &window);
    attr("lineOrder", "lineOrder", &[0]); // INCREASING_Y
    attr("pixelAspectRatio", "float", &1f32.to_le_bytes());
    let centre: Vec<u8> = [0f32, 0.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    attr("screenWindowCenter", "v2f", &centre);
    attr("screenWindowWidth", "float", &1f32.to_le_bytes());
    out.push(0); // end of header
    // Line offset table, then the blocks: y, byte count, the line's floats.
    let line_bytes = width as usize * 4;
    let table_end = out.len() + height as usize * 8;
    for y in 0..height as usize {
        let offset = table_end + y * (8 + line_bytes);
        out.extend_from_slice(&(offset as u64).to_le_bytes());
    }
    for (y, line) in data.chunks_exact(width as usize).enumerate() {
        out.extend_from_slice(&(y as i32).to_le_bytes());
        out.extend_from_slice(&(line_bytes as i32).to_le_bytes());
        for v in line {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reads back what `encode_gray` wrote, following the format description
    /// independently of the writer's code: header attributes by name, then the offset
    /// table.
    fn decode(bytes: &[u8]) -> (i32, i32, Vec<f32>, usize) {
        assert_eq!(&bytes[..4], &[0x76, 0x2f, 0x31, 0x01]);
        let mut k = 8;
        let cstr = |k: &mut usize| {
            let end = bytes[*k..].iter().position(|&b| b == 0).unwrap() + *k;
            let s = std::str::from_utf8(&bytes[*k..end]).unwrap().to_string();
            *k = end + 1;
            s
        };
        let mut window = [0i32; 4];
        loop {
            let name = cstr(&mut k);
            if name.is_empty() {
                break;
            }
            let _kind = cstr(&mut k);
            let size = u32::from_le_bytes(bytes[k..k + 4].try_into().unwrap()) as usize;
            k += 4;
            if name == "dataWindow" {
                for (i, w) in window.iter_mut().enumerate() {
                    *w = i32::from_le_bytes(bytes[k + 4 * i..k + 4 * i + 4].try_into().unwrap());
                }
            }
            k += size;
        }
        let (w, h) = (window[2] - window[0] + 1, window[3] - window[1] + 1);
        let mut data = Vec::new();
        let mut end = 0;
        for y in 0..h as usize {
            let off =
                u64::from_le_bytes(bytes[k + 8 * y..k + 8 * y + 8].try_into().unwrap()) as usize;
            assert_eq!(
                i32::from_le_bytes(bytes[off..off + 4].try_into().unwrap()),
                y as i32
            );
            let n = i32::from_le_bytes(bytes[off + 4..off + 8].try_into().unwrap()) as usize;
            assert_eq!(n, w as usize * 4);
            for x in 0..w as usize {
                let p = off + 8 + 4 * x;
                data.push(f32::from_le_bytes(bytes[p..p + 4].try_into().unwrap()));
            }
            end = end.max(off + 8 + n);
        }
        (w, h, data, end)
    }

    #[test]
    fn an_image_reads_back_through_its_offset_table() {
        let data: Vec<f32> = (0..12).map(|i| i as f32 * 0.25).collect();
        let bytes = encode_gray(4, 3, &data);
        let (w, h, back, end) = decode(&bytes);
        assert_eq!((w, h), (4, 3));
        assert_eq!(back, data);
        // The last block ends the file.
        assert_eq!(end, bytes.len());
    }
}

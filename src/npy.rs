//! Reading `.npy` files safely: the header is parsed first and the byte size
//! it claims is checked against the file's length and the memory budget
//! before anything of that size is allocated. Every `.npy` load path (grids,
//! rays, `--grad-from`, goldens, reference images) goes through here.

use std::io::Read;
use std::path::Path;

use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};

/// The element types hotpath reads (SCENES.md "Files").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    F32,
    F64,
    I32,
    U32,
    U8,
}

impl Dtype {
    /// The numpy name (`float32`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Dtype::F32 => "float32",
            Dtype::F64 => "float64",
            Dtype::I32 => "int32",
            Dtype::U32 => "uint32",
            Dtype::U8 => "uint8",
        }
    }

    pub fn size(self) -> u64 {
        match self {
            Dtype::F32 | Dtype::I32 | Dtype::U32 => 4,
            Dtype::F64 => 8,
            Dtype::U8 => 1,
        }
    }

    fn from_descr(d: &str) -> Option<Dtype> {
        match d {
            "<f4" => Some(Dtype::F32),
            "<f8" => Some(Dtype::F64),
            "<i4" => Some(Dtype::I32),
            "<u4" => Some(Dtype::U32),
            "|u1" | "<u1" => Some(Dtype::U8),
            _ => None,
        }
    }
}

/// A parsed `.npy` header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    /// Byte offset of the data.
    pub data_offset: u64,
    /// Bytes of data the header claims.
    pub data_bytes: u64,
}

const MAGIC: &[u8] = b"\x93NUMPY";
/// Longest header accepted (numpy writes under 200 bytes; it refuses over 10 000).
pub const MAX_HEADER_BYTES: usize = 65_536;
/// Most axes accepted (numpy's own limit is 64).
pub const MAX_NDIM: usize = 32;

/// Parses the header from the first bytes of a file (at least the whole
/// header). `what` names the file in errors.
pub fn parse_header(bytes: &[u8], what: &str) -> Result<Header> {
    let bad = |m: String| Error::invalid(what, format!("not a readable .npy file: {m}"));
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(bad("no \\x93NUMPY magic".into()));
    }
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10usize),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(bad("truncated header length".into()));
            }
            let l = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
            (usize::try_from(l).unwrap_or(usize::MAX), 12usize)
        }
        v => return Err(bad(format!("format version {v} is not 1, 2 or 3"))),
    };
    if len > MAX_HEADER_BYTES {
        return Err(bad(format!(
            "header of {len} bytes is over the {MAX_HEADER_BYTES}-byte limit"
        )));
    }
    let end = start + len;
    let text = bytes
        .get(start..end)
        .ok_or_else(|| bad(format!("header claims {len} bytes; the file is shorter")))?;
    let text = std::str::from_utf8(text).map_err(|_| bad("header is not UTF-8".into()))?;
    let dict = parse_dict(text).map_err(bad)?;
    let descr = dict
        .descr
        .ok_or_else(|| bad("header has no 'descr'".into()))?;
    let dtype = Dtype::from_descr(&descr).ok_or_else(|| {
        Error::invalid(
            what,
            format!(
                "unsupported .npy dtype {descr:?} (expected little-endian float32, float64, int32, uint32 or uint8, C order)"
            ),
        )
    })?;
    if dict.fortran != Some(false) {
        return Err(Error::invalid(
            what,
            "unsupported .npy layout: fortran_order must be False (C order)",
        ));
    }
    let shape = dict
        .shape
        .ok_or_else(|| bad("header has no 'shape'".into()))?;
    let count = shape
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d as u64));
    let data_bytes = count
        .and_then(|c| bytes_for(c, dtype.size()))
        .ok_or_else(|| bad(format!("shape {shape:?} overflows 64 bits of bytes")))?;
    Ok(Header {
        dtype,
        shape,
        data_offset: end as u64,
        data_bytes,
    })
}

#[derive(Default)]
struct Dict {
    descr: Option<String>,
    fortran: Option<bool>,
    shape: Option<Vec<usize>>,
}

/// Parses numpy's header dict: `{'descr': '<f4', 'fortran_order': False,
/// 'shape': (2, 3), }` (keys in any order).
fn parse_dict(text: &str) -> std::result::Result<Dict, String> {
    let t = text.trim_end_matches(['\n', ' ', '\0']).trim_start();
    let inner = t
        .strip_prefix('{')
        .and_then(|s| s.strip_suffix('}'))
        .ok_or("header is not a {...} dict")?;
    let mut d = Dict::default();
    let mut rest = inner.trim_start();
    while !rest.is_empty() {
        let (key, after) = quoted(rest).ok_or("expected a quoted key")?;
        let after = after
            .trim_start()
            .strip_prefix(':')
            .ok_or("expected ':' after a key")?
            .trim_start();
        let after = match key {
            "descr" => {
                let (v, a) = quoted(after).ok_or("'descr' is not a quoted string")?;
                d.descr = Some(v.to_string());
                a
            }
            "fortran_order" => {
                if let Some(a) = after.strip_prefix("False") {
                    d.fortran = Some(false);
                    a
                } else if let Some(a) = after.strip_prefix("True") {
                    d.fortran = Some(true);
                    a
                } else {
                    return Err("'fortran_order' is not True or False".into());
                }
            }
            "shape" => {
                let (v, a) = tuple(after)?;
                d.shape = Some(v);
                a
            }
            k => return Err(format!("unknown header key {k:?}")),
        };
        let after = after.trim_start();
        rest = match after.strip_prefix(',') {
            Some(a) => a.trim_start(),
            None if after.is_empty() => after,
            None => return Err("expected ',' between entries".into()),
        };
    }
    Ok(d)
}

fn quoted(s: &str) -> Option<(&str, &str)> {
    let q = s.chars().next().filter(|c| *c == '\'' || *c == '"')?;
    let body = &s[1..];
    let end = body.find(q)?;
    Some((&body[..end], &body[end + 1..]))
}

fn tuple(s: &str) -> std::result::Result<(Vec<usize>, &str), String> {
    let body = s.strip_prefix('(').ok_or("'shape' is not a tuple")?;
    let end = body.find(')').ok_or("'shape' tuple is not closed")?;
    let mut v = Vec::new();
    for part in body[..end].split(',') {
        let p = part.trim();
        if p.is_empty() {
            continue;
        }
        if v.len() == MAX_NDIM {
            return Err(format!("'shape' has more than {MAX_NDIM} axes"));
        }
        let n: usize = p
            .parse()
            .map_err(|_| format!("'shape' entry {p:?} is not a non-negative integer"))?;
        v.push(n);
    }
    Ok((v, &body[end + 1..]))
}

/// A `.npy` file's header and raw little-endian data.
pub struct Raw {
    pub header: Header,
    pub data: Vec<u8>,
}

/// Reads the header, checks the claimed size against the file and the
/// budget, and only then reads the data. `check` may refuse the header
/// (dtype, shape) before the data is read.
pub fn read(path: &Path, budget: MemBudget, check: impl Fn(&Header) -> Result<()>) -> Result<Raw> {
    let at = path.display().to_string();
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::invalid(at, "is a directory, not a .npy file"));
    }
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut head = Vec::new();
    (&mut f)
        .take((MAX_HEADER_BYTES + 12) as u64)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, e))?;
    let h = parse_header(&head, &at)?;
    check(&h)?;
    let have = meta.len().saturating_sub(h.data_offset);
    if have != h.data_bytes {
        return Err(Error::invalid(
            at,
            format!(
                "header claims shape {:?} of {} ({} bytes) but the file holds {have} data bytes",
                h.shape,
                h.dtype.name(),
                h.data_bytes
            ),
        ));
    }
    budget.check(
        &format!("{at} ({:?} {})", h.shape, h.dtype.name()),
        Some(h.data_bytes),
    )?;
    let mut data = head.split_off((h.data_offset as usize).min(head.len()));
    data.reserve_exact((h.data_bytes as usize).saturating_sub(data.len()));
    f.read_to_end(&mut data).map_err(|e| Error::io(path, e))?;
    if data.len() as u64 != h.data_bytes {
        return Err(Error::invalid(at, "file changed while being read"));
    }
    Ok(Raw { header: h, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(header: &str, data: usize) -> Vec<u8> {
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut b = MAGIC.to_vec();
        b.extend([1, 0]);
        b.extend((h.len() as u16).to_le_bytes());
        b.extend(h.as_bytes());
        b.extend(std::iter::repeat_n(0u8, data));
        b
    }

    #[test]
    fn numpy_headers_parse_in_any_key_order() {
        let b = file(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }",
            24,
        );
        let h = parse_header(&b, "x").unwrap();
        assert_eq!(
            (h.dtype, h.shape.clone(), h.data_bytes),
            (Dtype::F32, vec![2, 3], 24)
        );
        let b = file("{'shape': (5,), 'fortran_order': False, 'descr': '|u1'}", 5);
        assert_eq!(parse_header(&b, "x").unwrap().shape, vec![5]);
        let b = file("{'descr': '<f8', 'fortran_order': False, 'shape': ()}", 8);
        assert_eq!(parse_header(&b, "x").unwrap().data_bytes, 8);
    }

    #[test]
    fn a_header_claiming_more_than_the_file_holds_is_refused_before_reading() {
        let dir = std::env::temp_dir().join(format!("hp-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("huge.npy");
        std::fs::write(
            &p,
            file(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (3000, 3000, 3000), }",
                64,
            ),
        )
        .unwrap();
        let e = read(&p, MemBudget::fixed(1 << 40), |_| Ok(()))
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("108000000000 bytes") && e.contains("holds 64"),
            "{e}"
        );
        let e = read(&p, MemBudget::fixed(1 << 20), |_| Ok(()))
            .err()
            .unwrap();
        assert!(e.to_string().contains("holds 64"), "{e}");
        let e = read(&dir, MemBudget::fixed(1 << 20), |_| Ok(()))
            .err()
            .unwrap();
        assert!(e.to_string().contains("is a directory"), "{e}");
    }

    #[test]
    fn overflowing_big_endian_and_fortran_headers_are_refused() {
        for (hdr, want) in [
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (18446744073709551615, 2), }",
                "overflows",
            ),
            (
                "{'descr': '>f4', 'fortran_order': False, 'shape': (2,), }",
                "unsupported .npy dtype",
            ),
            (
                "{'descr': '<f4', 'fortran_order': True, 'shape': (2,), }",
                "fortran_order",
            ),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (-2,), }",
                "non-negative",
            ),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (2,) ",
                "dict",
            ),
        ] {
            let e = parse_header(&file(hdr, 0), "x").unwrap_err().to_string();
            assert!(e.contains(want), "{hdr}: {e}");
        }
    }

    #[test]
    fn a_file_over_the_budget_is_refused_without_reading_it() {
        let dir = std::env::temp_dir().join(format!("hp-npy-b-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("big.npy");
        std::fs::write(
            &p,
            file(
                "{'descr': '<f8', 'fortran_order': False, 'shape': (1000,), }",
                8000,
            ),
        )
        .unwrap();
        assert!(read(&p, MemBudget::fixed(8000), |_| Ok(())).is_ok());
        let e = read(&p, MemBudget::fixed(7999), |_| Ok(())).err().unwrap();
        assert!(matches!(e, Error::OutOfMemory { needed: 8000, .. }), "{e}");
    }
}

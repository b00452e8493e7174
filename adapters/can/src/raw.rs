//! Pure: raw-frame encoding. A field is an integer of 8, 16 or 32 bits, signed or unsigned,
//! little- or big-endian, at a byte offset in a frame; several fields share one frame.
//!
//! Encoding clamps a value to what the field can hold, so a value outside its range becomes
//! the nearest end rather than wrapping around (a wrapped motor command reverses the motor).

use crate::error::FrameError;
use serde::{Deserialize, Serialize};

/// A field's width.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Width {
    /// One byte.
    Bits8,
    /// Two bytes.
    Bits16,
    /// Four bytes.
    Bits32,
}

impl Width {
    /// The width for `bits`, if it is 8, 16 or 32.
    pub fn from_bits(bits: i64) -> Option<Width> {
        match bits {
            8 => Some(Width::Bits8),
            16 => Some(Width::Bits16),
            32 => Some(Width::Bits32),
            _ => None,
        }
    }

    /// Bytes the field takes.
    pub fn bytes(self) -> usize {
        match self {
            Width::Bits8 => 1,
            Width::Bits16 => 2,
            Width::Bits32 => 4,
        }
    }

    /// Bits the field takes.
    pub fn bits(self) -> u32 {
        8 * self.bytes() as u32
    }
}

/// Byte order of a multi-byte field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Endian {
    /// Least significant byte first (Intel; most CAN servos and DroneCAN).
    #[default]
    Little,
    /// Most significant byte first (Motorola).
    Big,
}

/// Where and how a value sits in a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct FieldLayout {
    /// First byte of the field.
    pub offset: usize,
    /// Width.
    pub width: Width,
    /// Byte order.
    pub endian: Endian,
    /// Two's complement (`true`) or unsigned.
    pub signed: bool,
}

impl FieldLayout {
    /// The smallest and largest value the field holds.
    pub fn range(&self) -> (i64, i64) {
        let bits = self.width.bits();
        if self.signed {
            (-(1i64 << (bits - 1)), (1i64 << (bits - 1)) - 1)
        } else {
            (0, (1i64 << bits) - 1)
        }
    }

    /// The byte after the field.
    pub fn end(&self) -> usize {
        self.offset.saturating_add(self.width.bytes())
    }

    /// Whether this field and `other` share a byte.
    pub fn overlaps(&self, other: &FieldLayout) -> bool {
        self.offset < other.end() && other.offset < self.end()
    }

    fn bytes_in(&self, buf_len: usize) -> Result<std::ops::Range<usize>, FrameError> {
        if self.end() > buf_len {
            return Err(FrameError::FieldOutOfFrame {
                offset: self.offset,
                bytes: self.width.bytes(),
                frame_len: buf_len,
            });
        }
        Ok(self.offset..self.end())
    }

    /// Writes `value`, clamped to [`FieldLayout::range`], into `buf`.
    ///
    /// # Errors
    /// [`FrameError::FieldOutOfFrame`] if the field reaches past `buf`.
    pub fn encode(&self, buf: &mut [u8], value: i64) -> Result<(), FrameError> {
        let range = self.bytes_in(buf.len())?;
        let (lo, hi) = self.range();
        // Two's complement of the clamped value; the low `bits` bits are the field.
        let raw = value.clamp(lo, hi) as u64;
        let n = self.width.bytes();
        let le = raw.to_le_bytes();
        let dest = &mut buf[range];
        match self.endian {
            Endian::Little => dest.copy_from_slice(&le[..n]),
            Endian::Big => {
                for (d, s) in dest.iter_mut().zip(le[..n].iter().rev()) {
                    *d = *s;
                }
            }
        }
        Ok(())
    }

    /// Reads the field's value from `buf` (the inverse of [`FieldLayout::encode`] within range).
    ///
    /// # Errors
    /// [`FrameError::FieldOutOfFrame`] if the field reaches past `buf`.
    pub fn decode(&self, buf: &[u8]) -> Result<i64, FrameError> {
        let range = self.bytes_in(buf.len())?;
        let src = &buf[range];
        let mut le = [0u8; 8];
        let n = self.width.bytes();
        match self.endian {
            Endian::Little => le[..n].copy_from_slice(src),
            Endian::Big => {
                for (d, s) in le[..n].iter_mut().zip(src.iter().rev()) {
                    *d = *s;
                }
            }
        }
        let raw = u64::from_le_bytes(le);
        let bits = self.width.bits();
        Ok(if self.signed && raw & (1u64 << (bits - 1)) != 0 {
            raw as i64 - (1i64 << bits)
        } else {
            raw as i64
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn field(offset: usize, bits: i64, endian: Endian, signed: bool) -> FieldLayout {
        FieldLayout {
            offset,
            width: Width::from_bits(bits).expect("8, 16 or 32"),
            endian,
            signed,
        }
    }

    fn encoded(layout: FieldLayout, len: usize, value: i64) -> Vec<u8> {
        let mut buf = vec![0u8; len];
        layout.encode(&mut buf, value).expect("fits");
        buf
    }

    #[test]
    fn widths_endianness_and_signedness_give_exact_bytes() {
        use Endian::{Big, Little};
        // (layout, value, expected bytes of a frame of that length)
        let cases: [(FieldLayout, i64, &[u8]); 10] = [
            (field(0, 8, Little, false), 200, &[0xC8]),
            (field(0, 8, Little, true), -2, &[0xFE]),
            (field(1, 16, Little, true), -1000, &[0x00, 0x18, 0xFC]),
            (field(1, 16, Big, true), -1000, &[0x00, 0xFC, 0x18]),
            (field(0, 16, Little, false), 0x1234, &[0x34, 0x12]),
            (field(0, 16, Big, false), 0x1234, &[0x12, 0x34]),
            (
                field(0, 32, Little, true),
                -100_000,
                &[0x60, 0x79, 0xFE, 0xFF],
            ),
            (
                field(0, 32, Big, false),
                0xDEAD_BEEF,
                &[0xDE, 0xAD, 0xBE, 0xEF],
            ),
            (field(4, 32, Little, false), 1, &[0, 0, 0, 0, 1, 0, 0, 0]),
            (field(7, 8, Big, false), 0xAA, &[0, 0, 0, 0, 0, 0, 0, 0xAA]),
        ];
        for (layout, value, expected) in cases {
            assert_eq!(
                encoded(layout, expected.len(), value),
                expected,
                "{layout:?} {value}"
            );
            assert_eq!(layout.decode(expected), Ok(value), "{layout:?}");
        }
    }

    #[test]
    fn out_of_range_values_clamp_instead_of_wrapping() {
        let u8f = field(0, 8, Endian::Little, false);
        assert_eq!(encoded(u8f, 1, 300), [0xFF]);
        assert_eq!(encoded(u8f, 1, -5), [0x00]);
        let i16f = field(0, 16, Endian::Big, true);
        assert_eq!(encoded(i16f, 2, 40_000), [0x7F, 0xFF]);
        assert_eq!(encoded(i16f, 2, -40_000), [0x80, 0x00]);
        let u32f = field(0, 32, Endian::Little, false);
        assert_eq!(encoded(u32f, 4, i64::MAX), [0xFF; 4]);
    }

    #[test]
    fn a_field_past_the_frame_is_an_error_not_a_panic() {
        let f = field(7, 16, Endian::Little, false);
        let mut buf = [0u8; 8];
        assert_eq!(
            f.encode(&mut buf, 1),
            Err(FrameError::FieldOutOfFrame {
                offset: 7,
                bytes: 2,
                frame_len: 8
            })
        );
        assert!(f.decode(&buf).is_err());
        let far = field(usize::MAX, 32, Endian::Little, true);
        assert!(far.encode(&mut buf, 1).is_err());
    }

    #[test]
    fn shared_frame_fields_do_not_disturb_each_other() {
        let a = field(0, 16, Endian::Little, true);
        let b = field(2, 16, Endian::Big, false);
        let c = field(4, 8, Endian::Little, false);
        let mut buf = [0u8; 5];
        a.encode(&mut buf, -1).expect("fits");
        b.encode(&mut buf, 0x0102).expect("fits");
        c.encode(&mut buf, 7).expect("fits");
        assert_eq!(buf, [0xFF, 0xFF, 0x01, 0x02, 0x07]);
        assert!(a.overlaps(&field(1, 8, Endian::Little, false)));
        assert!(!a.overlaps(&b));
    }

    fn any_layout() -> impl Strategy<Value = FieldLayout> {
        (
            0usize..70,
            prop_oneof![Just(8i64), Just(16), Just(32)],
            any::<bool>(),
            any::<bool>(),
        )
            .prop_map(|(offset, bits, big, signed)| {
                field(
                    offset,
                    bits,
                    if big { Endian::Big } else { Endian::Little },
                    signed,
                )
            })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4_000))]

        /// Encoding never panics, whatever the layout, buffer and value; when the field fits,
        /// decoding gives back the value clamped to the field's range, and no other byte changes.
        #[test]
        fn encode_never_panics_and_round_trips(
            layout in any_layout(), len in 0usize..=64, value: i64, fill: u8,
        ) {
            let mut buf = vec![fill; len];
            let result = layout.encode(&mut buf, value);
            if layout.end() <= len {
                prop_assert!(result.is_ok());
                let (lo, hi) = layout.range();
                prop_assert_eq!(layout.decode(&buf), Ok(value.clamp(lo, hi)));
                for (i, b) in buf.iter().enumerate() {
                    if i < layout.offset || i >= layout.end() {
                        prop_assert_eq!(*b, fill);
                    }
                }
            } else {
                prop_assert!(result.is_err());
                prop_assert!(buf.iter().all(|b| *b == fill));
            }
        }
    }
}

//! Validating one raw frame (`[[output.frames]]`): its identifier, length and rate, and each
//! value in it: where it sits (offset, width, no overlap), its source and its scale.

use super::validate::{check_rate, int_scale, period_of};
use super::{FieldSettings, FrameSettings, RawFrameConfig, RawOutputConfig, SourceSettings};
use crate::bus::{
    CLASSIC_MAX_LEN, CanId, EXTENDED_ID_MAX, FD_LENGTHS, FD_MAX_LEN, STANDARD_ID_MAX,
};
use crate::raw::{FieldLayout, Width};
use rove_core::config::{Int, Unique};
use rove_core::error::ConfigErrors;

pub(super) fn validate_frame(
    f: &mut FrameSettings,
    i: usize,
    fd: bool,
    section_rate: i64,
    (names, ids): (&mut Unique<String>, &mut Unique<CanId>),
    errors: &mut ConfigErrors,
) -> Option<RawFrameConfig> {
    let extended = *f.extended.get_or_insert(false);
    let id = errors.required("id", &f.id).and_then(|id| {
        let fits = (u32::try_from(id).ok()).and_then(|id| CanId::new(id, extended).ok());
        if fits.is_none() {
            let limit = if extended {
                EXTENDED_ID_MAX
            } else {
                STANDARD_ID_MAX
            };
            let hint = (!extended && (0..=i64::from(EXTENDED_ID_MAX)).contains(&id))
                .then_some(" (set extended = true for a 29-bit identifier)");
            let shown = u64::try_from(id).map_or(id.to_string(), |id| format!("0x{id:X}"));
            let rule = format!("must be 0..=0x{limit:X}{}", hint.unwrap_or_default());
            errors.add("id", shown, rule);
        }
        fits
    });
    let capacity = if fd { FD_MAX_LEN } else { CLASSIC_MAX_LEN };
    let length = f.length.and_then(|len| {
        let ok = (usize::try_from(len).ok())
            .filter(|l| *l <= CLASSIC_MAX_LEN || (fd && FD_LENGTHS.contains(l)));
        if ok.is_none() {
            let rule = match fd {
                true => "must be 0..=8, 12, 16, 20, 24, 32, 48 or 64 bytes",
                false => "must be 0..=8 bytes (longer frames need fd = true)",
            };
            errors.add("length", len, rule);
        }
        ok
    });
    let rate = check_rate(&mut f.rate_hz, section_rate, errors);
    if f.outputs.is_empty() {
        let rule = "a frame needs at least one [[output.frames.outputs]]";
        errors.add("outputs", "[]", rule);
    }
    let limit = length.unwrap_or(capacity);
    let mut outputs: Vec<RawOutputConfig> = Vec::new();
    let mut all_ok = id.is_some();
    for (j, o) in f.outputs.iter_mut().enumerate() {
        let mut oe = ConfigErrors::default();
        let default_name = format!("frames[{i}].outputs[{j}]");
        let output = validate_field(o, &default_name, limit, &outputs, &mut oe);
        if let Some(output) = &output {
            let (key, shown) = (format!("outputs[{j}].name"), format!("{:?}", output.name));
            let (name, owner) = (output.name.clone(), format!("{default_name}.name"));
            names.check(errors, name, owner, (&key, shown), "has the same name");
        }
        all_ok &= output.is_some();
        errors.extend_within(&format!("outputs[{j}]"), oe);
        outputs.extend(output);
    }
    // Checked on the id as written, so a frame with other errors still counts.
    if let Some(id) = id {
        let owner = format!("frames[{i}]");
        ids.check(errors, id, owner, ("id", id), "has the same identifier");
    }
    let id = id?;
    if !all_ok {
        return None;
    }
    let needed = outputs.iter().map(|o| o.layout.end()).max().unwrap_or(0);
    let length = length.unwrap_or_else(|| match needed <= CLASSIC_MAX_LEN {
        true => needed,
        false => FD_LENGTHS
            .into_iter()
            .find(|l| *l >= needed)
            .unwrap_or(FD_MAX_LEN),
    });
    f.length = Some(length as Int);
    let period = period_of(rate);
    Some(RawFrameConfig {
        id,
        length,
        period,
        outputs,
    })
}

fn validate_field(
    o: &mut FieldSettings,
    default_name: &str,
    frame_len: usize,
    earlier: &[RawOutputConfig],
    errors: &mut ConfigErrors,
) -> Option<RawOutputConfig> {
    (o.unknown).check(errors, FieldSettings::KNOWN);
    let name = (o.name.clone()).unwrap_or_else(|| default_name.into());
    if o.name.as_deref().is_some_and(|n| n.trim().is_empty()) {
        errors.add("name", "\"\"", "must not be empty");
    }
    let source = SourceSettings::validate(&o.source, errors);
    let bits = *o.width.get_or_insert(16);
    let width = Width::from_bits(bits);
    if width.is_none() {
        errors.add("width", bits, "must be 8, 16 or 32 (bits)");
    }
    let offset = errors.required("offset", &o.offset).and_then(|off| {
        let ok = usize::try_from(off).ok().filter(|o| *o < frame_len);
        if ok.is_none() {
            let rule = format!("must be 0..{frame_len} (the frame's bytes)");
            errors.add("offset", off, rule);
        }
        ok
    });
    let (offset, width) = (offset?, width?);
    let layout = FieldLayout {
        offset,
        width,
        endian: *o.endian.get_or_insert_default(),
        signed: *o.signed.get_or_insert(true),
    };
    let (end, bytes) = (layout.end(), width.bytes());
    let mut placed = true;
    if end > frame_len {
        let rule = format!(
            "offset + width ({offset} + {bytes} bytes) reaches past the frame's {frame_len} bytes"
        );
        errors.add("offset", offset, rule);
        placed = false;
    }
    if let Some(other) = earlier.iter().find(|e| e.layout.overlaps(&layout)) {
        let (o_start, o_end) = (other.layout.offset, other.layout.end());
        let rule = format!(
            "bytes {offset}..{end} overlap output {:?} (bytes {o_start}..{o_end})",
            other.name
        );
        errors.add("offset", offset, rule);
        placed = false;
    }
    let range = layout.range();
    // Signed fields default to a symmetric range.
    let defaults = (range.0 + Int::from(layout.signed), range.1);
    let (scale, failsafe) = int_scale(&mut o.scale, defaults, None, range, errors)?;
    placed.then_some(RawOutputConfig {
        name,
        source: source?,
        layout,
        scale,
        failsafe,
    })
}

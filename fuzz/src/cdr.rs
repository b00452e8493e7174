//! CDR decoding of rove's DDS topics, as a rove reader decodes a sample.
//!
//! The input is a serialized payload as it travels in an RTPS DATA submessage: a 2-byte
//! representation identifier, 2 option bytes, then the CDR body. rustdds's reader accepts the
//! sample only if the identifier is one its adapter supports, then decodes with
//! `CDRDeserializerAdapter` (with the key decoder for a keyed dispose). Here the same body is
//! offered to every type a rove reader decodes: DeviceInfo, VehicleStatus and ControlCommand
//! (through the gateway's keyed wrappers) and RequestControl.
//!
//! Checked: no panic; a sample that decodes re-encodes (little-endian, as rove writes) to
//! bytes that decode to the same value, and its key is the field the wrapper names.

use rove_core::msg::RequestControl;
use rove_gateway::dds::{KeyedControlCommand, KeyedDeviceInfo, KeyedVehicleStatus};
use rustdds::{
    CDRDeserializerAdapter, CDRSerializerAdapter, Keyed, RepresentationIdentifier,
    SerializedPayload,
};
use std::fmt::Debug;

/// Decodes `data` as a serialized payload of every rove topic type.
pub fn cdr(data: &[u8]) {
    let Ok(payload) = SerializedPayload::from_bytes(&rustdds::bytes::Bytes::copy_from_slice(data))
    else {
        return;
    };
    let rep = payload.representation_identifier;
    let body = &payload.value[..];
    keyed::<KeyedDeviceInfo>(rep, body, |v| v.0.device_id);
    keyed::<KeyedVehicleStatus>(rep, body, |v| v.0.vehicle_id);
    keyed::<KeyedControlCommand>(rep, body, |v| v.0.dest_id);
    unkeyed::<RequestControl>(rep, body);
}

/// What a keyed reader does with a DATA (value) or a DATA with a key only (dispose).
fn keyed<T>(rep: RepresentationIdentifier, body: &[u8], key_field: fn(&T) -> i64)
where
    T: Keyed<K = i64> + serde::Serialize + serde::de::DeserializeOwned + Debug,
{
    use rustdds::no_key::DeserializerAdapter as Values;
    use rustdds::with_key::DeserializerAdapter as Keys;
    let supported = <CDRDeserializerAdapter<T> as Values<T>>::supported_encodings();
    if !supported.contains(&rep) {
        return;
    }
    if let Ok(value) = <CDRDeserializerAdapter<T> as Values<T>>::from_bytes(body, rep) {
        assert_eq!(value.key(), key_field(&value));
        let again = round_trip(&value);
        assert_eq!(format!("{again:?}"), format!("{value:?}"));
    }
    let _ = <CDRDeserializerAdapter<T> as Keys<T>>::key_from_bytes(body, rep);
}

/// What the RequestControl reader (no key) does with a DATA.
fn unkeyed<T>(rep: RepresentationIdentifier, body: &[u8])
where
    T: serde::Serialize + serde::de::DeserializeOwned + Debug + PartialEq,
{
    use rustdds::no_key::DeserializerAdapter;
    let supported = <CDRDeserializerAdapter<T> as DeserializerAdapter<T>>::supported_encodings();
    if !supported.contains(&rep) {
        return;
    }
    if let Ok(value) = <CDRDeserializerAdapter<T> as DeserializerAdapter<T>>::from_bytes(body, rep)
    {
        assert_eq!(round_trip(&value), value);
    }
}

/// `value` encoded as rove's writers encode it, and decoded again.
fn round_trip<T>(value: &T) -> T
where
    T: serde::Serialize + serde::de::DeserializeOwned + Debug,
{
    use rustdds::no_key::{DeserializerAdapter, SerializerAdapter};
    let bytes = <CDRSerializerAdapter<T> as SerializerAdapter<T>>::to_bytes(value)
        .unwrap_or_else(|e| panic!("{value:?} decoded but does not encode: {e}"));
    <CDRDeserializerAdapter<T> as DeserializerAdapter<T>>::from_bytes(
        &bytes,
        RepresentationIdentifier::CDR_LE,
    )
    .unwrap_or_else(|e| panic!("{value:?} encodes to bytes that do not decode: {e}"))
}

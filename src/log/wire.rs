//! Decoding of the frequent messages into reused buffers, without allocating once the buffers
//! have their size (the channel and state names repeat from message to message), and their
//! encoding: `encode_*` write exactly the bytes prost writes (proto3: zero scalars and empty
//! strings omitted, doubles packed, fields in number order; tested against prost on varied
//! messages), several times cheaper than prost's generic path, which measures every nested
//! length before writing (docs/performance.md): mjsafe's per-step messages, `/prediction`, and
//! Foxglove's `/scene` and `/tf` (a scene update holding primitives mjsafe does not draw goes
//! through prost). Messages are destructured field by field, so a field added to the schema
//! fails to compile here until it is encoded.
//!
//! Each `merge_*` accepts the plain encoding prost writes (known fields with their proto3 wire
//! types, packed or unpacked doubles, UTF-8 strings) and gives the message prost would decode;
//! anything else (unknown fields, other wire types, malformed bytes) makes it return `None`, and
//! the caller decodes with prost, which then gives the same message or the same error as before.

use foxglove::messages::{
    Color, CubePrimitive, CylinderPrimitive, Duration, FrameTransform, KeyValuePair, LinePrimitive, Point3, Pose,
    Quaternion, SceneEntity, SceneEntityDeletion, SceneUpdate, Timestamp, Vector3,
};

use crate::log::proto;

const VARINT: u64 = 0;
const FIXED64: u64 = 1;
const LEN: u64 = 2;

struct Fields<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Fields<'a> {
    fn new(buf: &'a [u8]) -> Self {
        Fields { buf, pos: 0 }
    }

    fn done(&self) -> bool {
        self.pos >= self.buf.len()
    }

    /// A varint as prost reads it (at most 10 bytes, the 10th at most 1).
    #[inline]
    fn varint(&mut self) -> Option<u64> {
        // Keys, lengths and flags here are one byte.
        let first = *self.buf.get(self.pos)?;
        if first < 0x80 {
            self.pos += 1;
            return Some(u64::from(first));
        }
        self.long_varint()
    }

    /// [`Fields::varint`] of two bytes or more.
    #[inline(never)]
    fn long_varint(&mut self) -> Option<u64> {
        let mut value = 0u64;
        for i in 0..10 {
            let b = *self.buf.get(self.pos)?;
            self.pos += 1;
            if i == 9 && b > 1 {
                return None;
            }
            value |= u64::from(b & 0x7f) << (7 * i);
            if b < 0x80 {
                return Some(value);
            }
        }
        None
    }

    /// (field number, wire type) of the next field.
    #[inline]
    fn key(&mut self) -> Option<(u64, u64)> {
        let key = self.varint()?;
        Some((key >> 3, key & 7))
    }

    fn f64(&mut self) -> Option<f64> {
        let bytes = self.buf.get(self.pos..self.pos + 8)?;
        self.pos += 8;
        Some(f64::from_le_bytes(bytes.try_into().ok()?))
    }

    fn bytes(&mut self) -> Option<&'a [u8]> {
        let len = usize::try_from(self.varint()?).ok()?;
        let end = self.pos.checked_add(len)?;
        let bytes = self.buf.get(self.pos..end)?;
        self.pos = end;
        Some(bytes)
    }

    /// Packed doubles, appended to `out`.
    fn packed_f64(&mut self, out: &mut Vec<f64>) -> Option<()> {
        let bytes = self.bytes()?;
        if bytes.len() % 8 != 0 {
            return None;
        }
        out.extend(
            bytes
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
        );
        Some(())
    }

    /// A repeated double field (packed or not), appended to `out`.
    fn repeated_f64(&mut self, wire: u64, out: &mut Vec<f64>) -> Option<()> {
        match wire {
            LEN => self.packed_f64(out),
            FIXED64 => {
                out.push(self.f64()?);
                Some(())
            }
            _ => None,
        }
    }
}

/// Element `k` of a repeated string field := `bytes` (UTF-8, else `None`), reusing the
/// element's buffer; an unchanged string (the usual case) is only compared.
fn set_string(list: &mut Vec<String>, k: usize, bytes: &[u8]) -> Option<()> {
    match list.get_mut(k) {
        Some(old) => set_str(old, bytes)?,
        None => list.push(std::str::from_utf8(bytes).ok()?.to_owned()),
    }
    Some(())
}

fn set_str(old: &mut String, bytes: &[u8]) -> Option<()> {
    if old.as_bytes() != bytes {
        let s = std::str::from_utf8(bytes).ok()?;
        old.clear();
        old.push_str(s);
    }
    Some(())
}

pub(crate) fn merge_state(buf: &[u8], m: &mut proto::State) -> Option<()> {
    let mut r = Fields::new(buf);
    let mut names = 0;
    m.time = 0.0;
    m.step = 0;
    m.values.clear();
    while !r.done() {
        match r.key()? {
            (1, FIXED64) => m.time = r.f64()?,
            (2, VARINT) => m.step = r.varint()?,
            (3, LEN) => {
                set_string(&mut m.names, names, r.bytes()?)?;
                names += 1;
            }
            (4, wire) => r.repeated_f64(wire, &mut m.values)?,
            _ => return None,
        }
    }
    m.names.truncate(names);
    Some(())
}

pub(crate) fn merge_issued(buf: &[u8], m: &mut proto::IssuedCommand) -> Option<()> {
    let mut r = Fields::new(buf);
    let mut channels = 0;
    m.time = 0.0;
    m.nominal.clear();
    m.filtered.clear();
    while !r.done() {
        match r.key()? {
            (1, FIXED64) => m.time = r.f64()?,
            (2, LEN) => {
                set_string(&mut m.channels, channels, r.bytes()?)?;
                channels += 1;
            }
            (3, wire) => r.repeated_f64(wire, &mut m.nominal)?,
            (4, wire) => r.repeated_f64(wire, &mut m.filtered)?,
            _ => return None,
        }
    }
    m.channels.truncate(channels);
    Some(())
}

pub(crate) fn merge_filter(buf: &[u8], m: &mut proto::Filter) -> Option<()> {
    let mut r = Fields::new(buf);
    let mut channels = 0;
    m.time = 0.0;
    m.active = false;
    m.correction.clear();
    m.infeasible = false;
    m.mu = 0.0;
    m.left_out = 0;
    let mut unmet = 0;
    m.shortfall.clear();
    while !r.done() {
        match r.key()? {
            (1, FIXED64) => m.time = r.f64()?,
            (2, VARINT) => m.active = r.varint()? != 0,
            (3, LEN) => {
                set_string(&mut m.channels, channels, r.bytes()?)?;
                channels += 1;
            }
            (4, wire) => r.repeated_f64(wire, &mut m.correction)?,
            (5, VARINT) => m.infeasible = r.varint()? != 0,
            (6, FIXED64) => m.mu = r.f64()?,
            (7, LEN) => {
                set_string(&mut m.unmet, unmet, r.bytes()?)?;
                unmet += 1;
            }
            (8, wire) => r.repeated_f64(wire, &mut m.shortfall)?,
            (9, VARINT) => m.left_out = r.varint()? as u32,
            _ => return None,
        }
    }
    m.channels.truncate(channels);
    m.unmet.truncate(unmet);
    Some(())
}

pub(crate) fn merge_barrier(buf: &[u8], m: &mut proto::Barrier) -> Option<()> {
    let mut r = Fields::new(buf);
    let mut barriers = 0;
    m.time = 0.0;
    while !r.done() {
        match r.key()? {
            (1, FIXED64) => m.time = r.f64()?,
            (2, LEN) => {
                let bytes = r.bytes()?;
                if barriers == m.barriers.len() {
                    m.barriers.push(proto::BarrierValue::default());
                }
                merge_barrier_value(bytes, &mut m.barriers[barriers])?;
                barriers += 1;
            }
            _ => return None,
        }
    }
    m.barriers.truncate(barriers);
    Some(())
}

fn merge_barrier_value(buf: &[u8], m: &mut proto::BarrierValue) -> Option<()> {
    let mut r = Fields::new(buf);
    let mut name = None;
    m.h = 0.0;
    m.constraint = 0.0;
    m.known = false;
    m.relative_degree = 0;
    m.clearance = 0.0;
    m.time_to_collision = 0.0;
    m.obstacle = false;
    while !r.done() {
        match r.key()? {
            (1, LEN) if name.is_none() => name = Some(r.bytes()?),
            (2, FIXED64) => m.h = r.f64()?,
            (3, FIXED64) => m.constraint = r.f64()?,
            (4, VARINT) => m.known = r.varint()? != 0,
            (5, VARINT) => m.relative_degree = r.varint()? as u32,
            (6, FIXED64) => m.clearance = r.f64()?,
            (7, FIXED64) => m.time_to_collision = r.f64()?,
            (8, VARINT) => m.obstacle = r.varint()? != 0,
            _ => return None,
        }
    }
    set_str(&mut m.name, name.unwrap_or(b""))?;
    Some(())
}

pub(crate) fn merge_prediction(buf: &[u8], m: &mut proto::Prediction) -> Option<()> {
    let mut r = Fields::new(buf);
    let mut channel = None;
    m.time = 0.0;
    m.issued_at = 0.0;
    m.horizon = 0.0;
    m.predicted.clear();
    m.realized.clear();
    m.error = 0.0;
    m.relative_error = 0.0;
    m.reused_chain = false;
    m.chain_mismatch = 0.0;
    m.actor_predicted.clear();
    m.actor_realized.clear();
    m.actor_error.clear();
    let mut actors = 0;
    while !r.done() {
        match r.key()? {
            (1, FIXED64) => m.time = r.f64()?,
            (2, LEN) if channel.is_none() => channel = Some(r.bytes()?),
            (3, FIXED64) => m.issued_at = r.f64()?,
            (4, FIXED64) => m.horizon = r.f64()?,
            (5, wire) => r.repeated_f64(wire, &mut m.predicted)?,
            (6, wire) => r.repeated_f64(wire, &mut m.realized)?,
            (7, FIXED64) => m.error = r.f64()?,
            (8, FIXED64) => m.relative_error = r.f64()?,
            (9, VARINT) => m.reused_chain = r.varint()? != 0,
            (10, FIXED64) => m.chain_mismatch = r.f64()?,
            (11, LEN) => {
                set_string(&mut m.actors, actors, r.bytes()?)?;
                actors += 1;
            }
            (12, wire) => r.repeated_f64(wire, &mut m.actor_predicted)?,
            (13, wire) => r.repeated_f64(wire, &mut m.actor_realized)?,
            (14, wire) => r.repeated_f64(wire, &mut m.actor_error)?,
            _ => return None,
        }
    }
    m.actors.truncate(actors);
    set_str(&mut m.channel, channel.unwrap_or(b""))?;
    Some(())
}

#[inline]
fn put_key(out: &mut Vec<u8>, field: u8, wire: u64) {
    // Field numbers here are < 16: the key is one byte.
    debug_assert!(field < 16);
    out.push((field << 3) | wire as u8);
}

#[inline]
fn put_varint(out: &mut Vec<u8>, mut value: u64) {
    while value >= 0x80 {
        out.push((value as u8) | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

#[inline]
fn put_f64(out: &mut Vec<u8>, field: u8, value: f64) {
    // proto3 omits 0 (and −0, which compares equal); NaN is written.
    if value != 0.0 {
        put_key(out, field, FIXED64);
        out.extend_from_slice(&value.to_le_bytes());
    }
}

#[inline]
fn put_u64(out: &mut Vec<u8>, field: u8, value: u64) {
    if value != 0 {
        put_key(out, field, VARINT);
        put_varint(out, value);
    }
}

/// An int32 or enum field (negative values take ten bytes, as prost writes them).
#[inline]
fn put_i32(out: &mut Vec<u8>, field: u8, value: i32) {
    if value != 0 {
        put_key(out, field, VARINT);
        put_varint(out, i64::from(value) as u64);
    }
}

#[inline]
fn put_bool(out: &mut Vec<u8>, field: u8, value: bool) {
    if value {
        put_key(out, field, VARINT);
        out.push(1);
    }
}

#[inline]
fn put_str(out: &mut Vec<u8>, field: u8, value: &str) {
    if !value.is_empty() {
        put_key(out, field, LEN);
        put_varint(out, value.len() as u64);
        out.extend_from_slice(value.as_bytes());
    }
}

fn put_packed_fixed32(out: &mut Vec<u8>, field: u8, values: &[u32]) {
    if !values.is_empty() {
        put_key(out, field, LEN);
        put_varint(out, 4 * values.len() as u64);
        for v in values {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// A length-delimited submessage written by `body` (its length prefix placed afterwards).
#[inline]
fn put_message(out: &mut Vec<u8>, field: u8, body: impl FnOnce(&mut Vec<u8>)) {
    put_message_guessing(out, field, 1, body);
}

/// [`put_message`] leaving room for a length prefix of `guess` bytes (1 or 2: a body of less
/// than 128 or 16384 bytes), which saves moving the body when the guess is right.
#[inline]
fn put_message_guessing(out: &mut Vec<u8>, field: u8, guess: usize, body: impl FnOnce(&mut Vec<u8>)) {
    debug_assert!(guess == 1 || guess == 2);
    put_key(out, field, LEN);
    let at = out.len();
    out.push(0);
    if guess == 2 {
        out.push(0);
    }
    body(out);
    let end = out.len();
    let mut length = (end - at - guess) as u64;
    // The guess was right (the usual case): the prefix in place.
    if guess == 1 && length < 0x80 {
        out[at] = length as u8;
        return;
    }
    if guess == 2 && (0x80..0x4000).contains(&length) {
        out[at] = (length as u8) | 0x80;
        out[at + 1] = (length >> 7) as u8;
        return;
    }
    // Another prefix width: move the body in place (no allocation once `out` has the room).
    let width = varint_len(length);
    if width > guess {
        out.resize(end + width - guess, 0);
        out.copy_within(at + guess..end, at + width);
    } else {
        out.copy_within(at + guess..end, at + width);
        out.truncate(end - (guess - width));
    }
    for byte in &mut out[at..at + width] {
        *byte = (length as u8) | 0x80;
        length >>= 7;
    }
    out[at + width - 1] &= 0x7f;
}

// mjsafe's own messages are flat (a barrier value is the one submessage, itself flat), so
// their size is cheap to compute exactly: each encoder first sizes the message, makes that
// much room at the end of the buffer at once, then writes the fields with plain stores (no
// capacity check, no call, per field).

/// Bytes of `value` as a varint (1 to 10).
fn varint_len(value: u64) -> usize {
    if value < 0x80 {
        1
    } else {
        (64 - value.leading_zeros() as usize).div_ceil(7)
    }
}

/// Bytes of a double field (omitted when 0 or −0).
fn f64_len(value: f64) -> usize {
    if value != 0.0 {
        9
    } else {
        0
    }
}

/// Bytes of a uint field (omitted when 0).
fn u64_len(value: u64) -> usize {
    if value != 0 {
        1 + varint_len(value)
    } else {
        0
    }
}

fn bool_len(value: bool) -> usize {
    if value {
        2
    } else {
        0
    }
}

/// Bytes of a length-delimited field of `len` bytes (its key, length and body).
fn len_field_len(len: usize) -> usize {
    1 + varint_len(len as u64) + len
}

/// Bytes of a string field (omitted when empty).
fn str_len(value: &str) -> usize {
    if value.is_empty() {
        0
    } else {
        len_field_len(value.len())
    }
}

/// Bytes of a repeated string field (every element, empty ones included).
fn strings_len(values: &[String]) -> usize {
    values.iter().map(|v| len_field_len(v.len())).sum()
}

/// Bytes of a packed double field (omitted when empty).
fn packed_f64_len(values: &[f64]) -> usize {
    if values.is_empty() {
        0
    } else {
        len_field_len(8 * values.len())
    }
}

/// The room made at the end of a buffer for a message of known size, filled front to back.
struct Room<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl<'a> Room<'a> {
    /// `size` bytes at the end of `out` (no allocation when `out` has the capacity).
    fn new(out: &'a mut Vec<u8>, size: usize) -> Room<'a> {
        let start = out.len();
        out.resize(start + size, 0);
        Room {
            buf: &mut out[start..],
            at: 0,
        }
    }

    /// Checks that the message filled its room exactly (a size function and its writer agree).
    fn done(self) {
        assert_eq!(self.at, self.buf.len(), "a message's size and its bytes disagree");
    }

    fn byte(&mut self, byte: u8) {
        self.buf[self.at] = byte;
        self.at += 1;
    }

    fn array<const N: usize>(&mut self, bytes: [u8; N]) {
        let end = self.at + N;
        let slot: &mut [u8; N] = (&mut self.buf[self.at..end]).try_into().expect("N bytes");
        *slot = bytes;
        self.at = end;
    }

    fn bytes(&mut self, bytes: &[u8]) {
        let end = self.at + bytes.len();
        self.buf[self.at..end].copy_from_slice(bytes);
        self.at = end;
    }

    fn key(&mut self, field: u8, wire: u64) {
        // Field numbers here are < 16: the key is one byte.
        debug_assert!(field < 16);
        self.byte((field << 3) | wire as u8);
    }

    fn varint(&mut self, mut value: u64) {
        while value >= 0x80 {
            self.byte((value as u8) | 0x80);
            value >>= 7;
        }
        self.byte(value as u8);
    }

    fn f64(&mut self, field: u8, value: f64) {
        // As put_f64: 0 and −0 omitted, NaN written.
        if value != 0.0 {
            let [a, b, c, d, e, f, g, h] = value.to_le_bytes();
            self.array([(field << 3) | FIXED64 as u8, a, b, c, d, e, f, g, h]);
        }
    }

    fn u64(&mut self, field: u8, value: u64) {
        if value != 0 {
            self.key(field, VARINT);
            self.varint(value);
        }
    }

    fn bool(&mut self, field: u8, value: bool) {
        if value {
            self.array([(field << 3) | VARINT as u8, 1]);
        }
    }

    /// The key and length of a length-delimited field of `len` bytes.
    #[inline(always)]
    fn len_prefix(&mut self, field: u8, len: usize) {
        if len < 0x80 {
            self.array([(field << 3) | LEN as u8, len as u8]);
        } else {
            self.key(field, LEN);
            self.varint(len as u64);
        }
    }

    fn str(&mut self, field: u8, value: &str) {
        if !value.is_empty() {
            self.len_prefix(field, value.len());
            self.bytes(value.as_bytes());
        }
    }

    fn strings(&mut self, field: u8, values: &[String]) {
        for value in values {
            self.len_prefix(field, value.len());
            self.bytes(value.as_bytes());
        }
    }

    fn packed_f64(&mut self, field: u8, values: &[f64]) {
        if !values.is_empty() {
            self.len_prefix(field, 8 * values.len());
            let end = self.at + 8 * values.len();
            let (slots, _) = self.buf[self.at..end].as_chunks_mut::<8>();
            for (slot, value) in slots.iter_mut().zip(values) {
                *slot = value.to_le_bytes();
            }
            self.at = end;
        }
    }
}

pub(crate) fn encode_state(m: &proto::State, out: &mut Vec<u8>) {
    let proto::State {
        time,
        step,
        names,
        values,
    } = m;
    let size = f64_len(*time) + u64_len(*step) + strings_len(names) + packed_f64_len(values);
    let mut room = Room::new(out, size);
    room.f64(1, *time);
    room.u64(2, *step);
    room.strings(3, names);
    room.packed_f64(4, values);
    room.done();
}

pub(crate) fn encode_issued(m: &proto::IssuedCommand, out: &mut Vec<u8>) {
    let proto::IssuedCommand {
        time,
        channels,
        nominal,
        filtered,
    } = m;
    let size = f64_len(*time) + strings_len(channels) + packed_f64_len(nominal) + packed_f64_len(filtered);
    let mut room = Room::new(out, size);
    room.f64(1, *time);
    room.strings(2, channels);
    room.packed_f64(3, nominal);
    room.packed_f64(4, filtered);
    room.done();
}

pub(crate) fn encode_applied(m: &proto::AppliedCommand, out: &mut Vec<u8>) {
    let proto::AppliedCommand {
        time,
        channels,
        values,
        issued_at,
    } = m;
    let size = f64_len(*time) + strings_len(channels) + packed_f64_len(values) + packed_f64_len(issued_at);
    let mut room = Room::new(out, size);
    room.f64(1, *time);
    room.strings(2, channels);
    room.packed_f64(3, values);
    room.packed_f64(4, issued_at);
    room.done();
}

pub(crate) fn encode_filter(m: &proto::Filter, out: &mut Vec<u8>) {
    let proto::Filter {
        time,
        active,
        channels,
        correction,
        infeasible,
        mu,
        unmet,
        shortfall,
        left_out,
    } = m;
    let size = f64_len(*time)
        + bool_len(*active)
        + strings_len(channels)
        + packed_f64_len(correction)
        + bool_len(*infeasible)
        + f64_len(*mu)
        + strings_len(unmet)
        + packed_f64_len(shortfall)
        + u64_len(u64::from(*left_out));
    let mut room = Room::new(out, size);
    room.f64(1, *time);
    room.bool(2, *active);
    room.strings(3, channels);
    room.packed_f64(4, correction);
    room.bool(5, *infeasible);
    room.f64(6, *mu);
    room.strings(7, unmet);
    room.packed_f64(8, shortfall);
    room.u64(9, u64::from(*left_out));
    room.done();
}

pub(crate) fn encode_barrier(m: &proto::Barrier, out: &mut Vec<u8>) {
    let proto::Barrier { time, barriers } = m;
    encode_named_values(
        out,
        *time,
        barriers,
        48,
        |v| &v.name,
        |out, value| {
            let proto::BarrierValue {
                name: _,
                h,
                constraint,
                known,
                relative_degree,
                clearance,
                time_to_collision,
                obstacle,
            } = value;
            push_f64(out, 2, *h);
            push_f64(out, 3, *constraint);
            if *known {
                out.extend_from_slice(&[(4 << 3) | VARINT as u8, 1]);
            }
            if *relative_degree != 0 {
                push_varint_key(out, 5, VARINT, u64::from(*relative_degree));
            }
            push_f64(out, 6, *clearance);
            push_f64(out, 7, *time_to_collision);
            if *obstacle {
                out.extend_from_slice(&[(8 << 3) | VARINT as u8, 1]);
            }
        },
    );
}

/// `/actors` as prost writes it.
pub(crate) fn encode_actors(m: &proto::Actors, out: &mut Vec<u8>) {
    let proto::Actors { time, actors } = m;
    encode_named_values(
        out,
        *time,
        actors,
        70,
        |v| &v.name,
        |out, value| {
            let proto::ActorValue {
                name: _,
                x,
                y,
                vx,
                vy,
                ax,
                ay,
                heading,
                absent,
            } = value;
            for (field, value) in (2..).zip([x, y, vx, vy, ax, ay, heading]) {
                push_f64(out, field, *value);
            }
            if *absent {
                out.extend_from_slice(&[(9 << 3) | VARINT as u8, 1]);
            }
        },
    );
}

/// A message of a time (field 1) and repeated values (field 2) that each begin with their name
/// (field 1), as prost writes it, in one pass: each value is written after a one-byte length,
/// patched once its size is known (a longer varint, for a value of 128 bytes or more, is
/// spliced in). `room`: a value's bytes besides its name, to reserve; `fields` writes the rest.
#[inline(always)]
fn encode_named_values<T>(
    out: &mut Vec<u8>,
    time: f64,
    values: &[T],
    room: usize,
    name: impl Fn(&T) -> &String,
    fields: impl Fn(&mut Vec<u8>, &T),
) {
    out.reserve(9 + values.iter().map(|v| room + name(v).len()).sum::<usize>());
    push_f64(out, 1, time);
    for value in values {
        out.push((2 << 3) | LEN as u8);
        let length_at = out.len();
        out.push(0);
        let name = name(value);
        if !name.is_empty() {
            push_varint_key(out, 1, LEN, name.len() as u64);
            out.extend_from_slice(name.as_bytes());
        }
        fields(out, value);
        patch_length(out, length_at);
    }
}

/// The one-byte length at `length_at` ← the bytes after it (a longer varint spliced in for
/// 128 bytes or more).
fn patch_length(out: &mut Vec<u8>, length_at: usize) {
    let length = out.len() - length_at - 1;
    if length < 0x80 {
        out[length_at] = length as u8;
    } else {
        let (mut prefix, mut width, mut rest) = ([0u8; 10], 0, length as u64);
        while rest >= 0x80 {
            (prefix[width], width, rest) = ((rest as u8) | 0x80, width + 1, rest >> 7);
        }
        prefix[width] = rest as u8;
        out.splice(length_at..=length_at, prefix[..=width].iter().copied());
    }
}

/// A double field (omitted when 0 or −0, as prost writes it; NaN written).
fn push_f64(out: &mut Vec<u8>, field: u8, value: f64) {
    if value != 0.0 {
        let [a, b, c, d, e, f, g, h] = value.to_le_bytes();
        out.extend_from_slice(&[(field << 3) | FIXED64 as u8, a, b, c, d, e, f, g, h]);
    }
}

/// A key (field < 16) and then a varint (a value, or a length).
fn push_varint_key(out: &mut Vec<u8>, field: u8, wire: u64, value: u64) {
    debug_assert!(field < 16);
    out.push((field << 3) | wire as u8);
    push_varint(out, value);
}

fn push_varint(out: &mut Vec<u8>, mut value: u64) {
    while value >= 0x80 {
        out.push((value as u8) | 0x80);
        value >>= 7;
    }
    out.push(value as u8);
}

pub(crate) fn encode_prediction(m: &proto::Prediction, out: &mut Vec<u8>) {
    let proto::Prediction {
        time,
        channel,
        issued_at,
        horizon,
        predicted,
        realized,
        error,
        relative_error,
        reused_chain,
        chain_mismatch,
        actors,
        actor_predicted,
        actor_realized,
        actor_error,
    } = m;
    let size = f64_len(*time)
        + str_len(channel)
        + f64_len(*issued_at)
        + f64_len(*horizon)
        + packed_f64_len(predicted)
        + packed_f64_len(realized)
        + f64_len(*error)
        + f64_len(*relative_error)
        + bool_len(*reused_chain)
        + f64_len(*chain_mismatch)
        + strings_len(actors)
        + packed_f64_len(actor_predicted)
        + packed_f64_len(actor_realized)
        + packed_f64_len(actor_error);
    let mut room = Room::new(out, size);
    room.f64(1, *time);
    room.str(2, channel);
    room.f64(3, *issued_at);
    room.f64(4, *horizon);
    room.packed_f64(5, predicted);
    room.packed_f64(6, realized);
    room.f64(7, *error);
    room.f64(8, *relative_error);
    room.bool(9, *reused_chain);
    room.f64(10, *chain_mismatch);
    room.strings(11, actors);
    room.packed_f64(12, actor_predicted);
    room.packed_f64(13, actor_realized);
    room.packed_f64(14, actor_error);
    room.done();
}

// Foxglove's messages (`/scene`, `/tf`): `*_fields` write a submessage's fields, `put_*` a
// whole submessage.

/// An optional submessage: nothing when absent, else written even when its body is empty.
#[inline]
fn put_optional<T>(out: &mut Vec<u8>, field: u8, value: &Option<T>, fields: impl Fn(&mut Vec<u8>, &T)) {
    if let Some(value) = value {
        put_message(out, field, |out| fields(out, value));
    }
}

/// A repeated submessage: every element, empty ones included.
#[inline]
fn put_repeated<T>(out: &mut Vec<u8>, field: u8, values: &[T], fields: impl Fn(&mut Vec<u8>, &T)) {
    for value in values {
        put_message(out, field, |out| fields(out, value));
    }
}

/// [`put_repeated`] for elements that usually take 128 bytes or more (entities, lines).
#[inline]
fn put_repeated_long<T>(out: &mut Vec<u8>, field: u8, values: &[T], fields: impl Fn(&mut Vec<u8>, &T)) {
    for value in values {
        put_message_guessing(out, field, 2, |out| fields(out, value));
    }
}

// Timestamp and Duration are foxglove's own wrappers (not generated) with private fields:
// read through their accessors instead of destructured.
#[inline]
fn timestamp_fields(out: &mut Vec<u8>, t: &Timestamp) {
    put_u64(out, 1, u64::from(t.sec()));
    put_u64(out, 2, u64::from(t.nsec()));
}

fn duration_fields(out: &mut Vec<u8>, d: &Duration) {
    put_i32(out, 1, d.sec());
    put_u64(out, 2, u64::from(d.nsec()));
}

/// A submessage of doubles only (fields 1, 2, … of Vector3, Point3, Quaternion, Color): at
/// most 38 bytes, so its length takes one byte. Assembled on the stack and appended whole
/// (a copy of constant size, inlined), then cut to its length: cheaper than a push per field.
#[inline]
fn put_doubles<const N: usize>(out: &mut Vec<u8>, field: u8, values: [f64; N]) {
    const { assert!(N <= 4) };
    let mut bytes = [0u8; 2 + 4 * 9];
    bytes[0] = (field << 3) | LEN as u8;
    let mut end = 2;
    for (number, value) in (1u8..).zip(values) {
        // As put_f64: 0 and −0 omitted.
        if value != 0.0 {
            // An array store, not a slice copy (which carries an overlap check in this profile).
            let [a, b, c, d, e, f, g, h] = value.to_le_bytes();
            let slot: &mut [u8; 9] = (&mut bytes[end..end + 9]).try_into().expect("9 bytes");
            *slot = [(number << 3) | FIXED64 as u8, a, b, c, d, e, f, g, h];
            end += 9;
        }
    }
    bytes[1] = (end - 2) as u8;
    let start = out.len();
    out.extend_from_slice(&bytes);
    out.truncate(start + end);
}

#[inline]
fn put_vector3(out: &mut Vec<u8>, field: u8, v: &Vector3) {
    let Vector3 { x, y, z } = *v;
    put_doubles(out, field, [x, y, z]);
}

#[inline]
fn put_point3(out: &mut Vec<u8>, field: u8, p: &Point3) {
    let Point3 { x, y, z } = *p;
    put_doubles(out, field, [x, y, z]);
}

#[inline]
fn put_quaternion(out: &mut Vec<u8>, field: u8, q: &Quaternion) {
    let Quaternion { x, y, z, w } = *q;
    put_doubles(out, field, [x, y, z, w]);
}

#[inline]
fn put_color(out: &mut Vec<u8>, field: u8, c: &Color) {
    let Color { r, g, b, a } = *c;
    put_doubles(out, field, [r, g, b, a]);
}

#[inline]
fn pose_fields(out: &mut Vec<u8>, p: &Pose) {
    let Pose { position, orientation } = p;
    if let Some(position) = position {
        put_vector3(out, 1, position);
    }
    if let Some(orientation) = orientation {
        put_quaternion(out, 2, orientation);
    }
}

fn key_value_fields(out: &mut Vec<u8>, kv: &KeyValuePair) {
    let KeyValuePair { key, value } = kv;
    put_str(out, 1, key);
    put_str(out, 2, value);
}

#[inline]
fn cube_fields(out: &mut Vec<u8>, c: &CubePrimitive) {
    let CubePrimitive { pose, size, color } = c;
    put_optional(out, 1, pose, pose_fields);
    if let Some(size) = size {
        put_vector3(out, 2, size);
    }
    if let Some(color) = color {
        put_color(out, 3, color);
    }
}

#[inline]
fn cylinder_fields(out: &mut Vec<u8>, c: &CylinderPrimitive) {
    let CylinderPrimitive {
        pose,
        size,
        bottom_scale,
        top_scale,
        color,
    } = c;
    put_optional(out, 1, pose, pose_fields);
    if let Some(size) = size {
        put_vector3(out, 2, size);
    }
    put_f64(out, 3, *bottom_scale);
    put_f64(out, 4, *top_scale);
    if let Some(color) = color {
        put_color(out, 5, color);
    }
}

#[inline]
fn line_fields(out: &mut Vec<u8>, l: &LinePrimitive) {
    let LinePrimitive {
        r#type,
        pose,
        thickness,
        scale_invariant,
        points,
        color,
        colors,
        indices,
    } = l;
    put_i32(out, 1, *r#type);
    put_optional(out, 2, pose, pose_fields);
    put_f64(out, 3, *thickness);
    put_bool(out, 4, *scale_invariant);
    for point in points {
        put_point3(out, 5, point);
    }
    if let Some(color) = color {
        put_color(out, 6, color);
    }
    for color in colors {
        put_color(out, 7, color);
    }
    put_packed_fixed32(out, 8, indices);
}

/// Whether an entity holds only the primitives mjsafe draws (cubes, cylinders, lines), which
/// [`entity_fields`] encodes.
fn hand_encoded(e: &SceneEntity) -> bool {
    e.arrows.is_empty() && e.spheres.is_empty() && e.triangles.is_empty() && e.texts.is_empty() && e.models.is_empty()
}

fn entity_fields(out: &mut Vec<u8>, e: &SceneEntity) {
    let SceneEntity {
        timestamp,
        frame_id,
        id,
        lifetime,
        frame_locked,
        metadata,
        arrows,
        cubes,
        spheres,
        cylinders,
        lines,
        triangles,
        texts,
        models,
    } = e;
    debug_assert!(arrows.is_empty() && spheres.is_empty() && triangles.is_empty());
    debug_assert!(texts.is_empty() && models.is_empty());
    put_optional(out, 1, timestamp, timestamp_fields);
    put_str(out, 2, frame_id);
    put_str(out, 3, id);
    put_optional(out, 4, lifetime, duration_fields);
    put_bool(out, 5, *frame_locked);
    put_repeated(out, 6, metadata, key_value_fields);
    put_repeated(out, 8, cubes, cube_fields);
    put_repeated(out, 10, cylinders, cylinder_fields);
    put_repeated_long(out, 11, lines, line_fields);
}

fn deletion_fields(out: &mut Vec<u8>, d: &SceneEntityDeletion) {
    let SceneEntityDeletion { timestamp, r#type, id } = d;
    put_optional(out, 1, timestamp, timestamp_fields);
    put_i32(out, 2, *r#type);
    put_str(out, 3, id);
}

/// A scene update; one with primitives mjsafe does not draw (arrows, spheres, triangles,
/// texts, models) goes through prost.
pub(crate) fn encode_scene_update(m: &SceneUpdate, out: &mut Vec<u8>) {
    let SceneUpdate { deletions, entities } = m;
    if !entities.iter().all(hand_encoded) {
        prost::Message::encode(m, out).expect("a Vec grows to fit any message");
        return;
    }
    put_repeated(out, 1, deletions, deletion_fields);
    put_repeated_long(out, 2, entities, entity_fields);
}

pub(crate) fn encode_frame_transform(m: &FrameTransform, out: &mut Vec<u8>) {
    let FrameTransform {
        timestamp,
        parent_frame_id,
        child_frame_id,
        translation,
        rotation,
    } = m;
    put_optional(out, 1, timestamp, timestamp_fields);
    put_str(out, 2, parent_frame_id);
    put_str(out, 3, child_frame_id);
    if let Some(translation) = translation {
        put_vector3(out, 4, translation);
    }
    if let Some(rotation) = rotation {
        put_quaternion(out, 5, rotation);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    /// Messages of varied shape: empty and non-empty lists, zeros (omitted by proto3), NaN,
    /// infinities, negative zero, changing names.
    fn states() -> Vec<proto::State> {
        vec![
            proto::State {
                time: 0.5,
                step: 250,
                names: vec!["x1".into(), "x2".into(), "heading".into(), "speed".into()],
                values: vec![-20.0, 0.0, -0.0, 3.0],
            },
            proto::State::default(),
            proto::State {
                time: f64::NAN,
                step: u64::MAX,
                names: vec!["é".into()],
                values: vec![f64::INFINITY, f64::NEG_INFINITY, 1e-300],
            },
            proto::State {
                time: 1.0,
                step: 1,
                names: vec!["x1".into(), "x2".into(), "heading".into(), "speed".into()],
                values: vec![1.0, 2.0],
            },
        ]
    }

    fn same_bits(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
    }

    #[test]
    fn fast_state_decoding_matches_prost_also_when_the_message_is_reused() {
        let mut reused = proto::State::default();
        for m in states() {
            let bytes = m.encode_to_vec();
            let expected = proto::State::decode(&bytes[..]).unwrap();
            assert!(merge_state(&bytes, &mut reused).is_some(), "{m:?}");
            assert_eq!(
                (reused.step, &reused.names, reused.time.to_bits()),
                (expected.step, &expected.names, expected.time.to_bits())
            );
            assert!(
                same_bits(&reused.values, &expected.values),
                "{reused:?} vs {expected:?}"
            );
        }
    }

    #[test]
    fn fast_decoding_of_the_other_per_step_messages_matches_prost() {
        let channels = vec!["steering".to_string(), "acceleration".to_string()];
        let issued = [
            proto::IssuedCommand {
                time: 2.75,
                channels: channels.clone(),
                nominal: vec![0.1, -0.2],
                filtered: vec![0.3, 0.0],
            },
            proto::IssuedCommand::default(),
        ];
        let mut reused = proto::IssuedCommand::default();
        for m in issued {
            let bytes = m.encode_to_vec();
            assert!(merge_issued(&bytes, &mut reused).is_some());
            assert_eq!(reused, proto::IssuedCommand::decode(&bytes[..]).unwrap());
        }
        let filters = [
            proto::Filter {
                time: 3.0,
                active: true,
                channels: channels.clone(),
                correction: vec![0.5, -1.5],
                infeasible: true,
                mu: -0.25,
                unmet: vec!["road_edge_0".to_string(), "obstacle_0".to_string()],
                shortfall: vec![0.75, 2.5],
                left_out: 1234,
            },
            proto::Filter::default(),
        ];
        let mut reused = proto::Filter::default();
        for m in filters {
            let bytes = m.encode_to_vec();
            assert!(merge_filter(&bytes, &mut reused).is_some());
            assert_eq!(reused, proto::Filter::decode(&bytes[..]).unwrap());
        }
        let barriers = [
            proto::Barrier {
                time: 4.0,
                barriers: vec![
                    proto::BarrierValue {
                        name: "obstacle_0".into(),
                        h: 12.5,
                        constraint: -3.0,
                        known: true,
                        relative_degree: 2,
                        clearance: 1.25,
                        time_to_collision: f64::INFINITY,
                        obstacle: true,
                    },
                    proto::BarrierValue {
                        name: "wall".into(),
                        ..Default::default()
                    },
                ],
            },
            proto::Barrier {
                time: 4.002,
                barriers: vec![proto::BarrierValue {
                    name: "obstacle_0".into(),
                    h: 12.0,
                    ..Default::default()
                }],
            },
        ];
        let mut reused = proto::Barrier::default();
        for m in barriers {
            let bytes = m.encode_to_vec();
            assert!(merge_barrier(&bytes, &mut reused).is_some());
            assert_eq!(reused, proto::Barrier::decode(&bytes[..]).unwrap());
        }
    }

    #[test]
    fn fast_prediction_decoding_matches_prost_also_when_the_message_is_reused() {
        let predictions = [
            proto::Prediction {
                time: 1.5,
                channel: "acceleration".into(),
                issued_at: 0.2,
                horizon: 1.3,
                predicted: vec![-20.0, 0.5, -0.0, 3.0],
                realized: vec![-19.9, 0.4, 0.01, f64::INFINITY],
                error: 0.125,
                relative_error: 1e-300,
                reused_chain: true,
                chain_mismatch: f64::NAN,
                actors: vec!["walker".into(), "".into()],
                actor_predicted: vec![0.5, -12.0, f64::NAN, f64::NAN],
                actor_realized: vec![0.5, -11.0, 3.0, -0.0],
                actor_error: vec![1.0, f64::NAN],
            },
            proto::Prediction::default(),
            proto::Prediction {
                actors: vec!["a".repeat(200)],
                actor_error: vec![2.5],
                ..Default::default()
            },
            proto::Prediction {
                time: 1.51,
                channel: "steering".into(),
                predicted: vec![1.0],
                error: -0.0,
                chain_mismatch: 2e-5,
                ..Default::default()
            },
            proto::Prediction {
                channel: "o".repeat(300),
                ..Default::default()
            },
        ];
        let mut reused = proto::Prediction::default();
        for m in predictions {
            let bytes = m.encode_to_vec();
            let expected = proto::Prediction::decode(&bytes[..]).unwrap();
            assert!(merge_prediction(&bytes, &mut reused).is_some(), "{m:?}");
            let bits = |m: &proto::Prediction| {
                let scalars = [
                    m.time,
                    m.issued_at,
                    m.horizon,
                    m.error,
                    m.relative_error,
                    m.chain_mismatch,
                ];
                (
                    scalars.map(f64::to_bits),
                    m.channel.clone(),
                    m.reused_chain,
                    m.actors.clone(),
                )
            };
            assert_eq!(bits(&reused), bits(&expected));
            assert!(
                same_bits(&reused.predicted, &expected.predicted) && same_bits(&reused.realized, &expected.realized)
            );
            assert!(
                same_bits(&reused.actor_predicted, &expected.actor_predicted)
                    && same_bits(&reused.actor_realized, &expected.actor_realized)
                    && same_bits(&reused.actor_error, &expected.actor_error)
            );
        }
        // A channel given twice (prost keeps the last): left to prost.
        let mut bytes = proto::Prediction {
            channel: "a".into(),
            ..Default::default()
        }
        .encode_to_vec();
        bytes.extend_from_slice(&[2 << 3 | 2, 1, b'b']);
        assert!(merge_prediction(&bytes, &mut reused).is_none());
    }

    #[test]
    fn unknown_fields_and_truncation_fall_back_to_prost() {
        let mut bytes = states()[0].encode_to_vec();
        let mut reused = proto::State::default();
        // Field 15, varint 1: not in the schema.
        bytes.extend_from_slice(&[15 << 3, 1]);
        assert!(merge_state(&bytes, &mut reused).is_none());
        let bytes = states()[0].encode_to_vec();
        assert!(merge_state(&bytes[..bytes.len() - 3], &mut reused).is_none());
    }

    #[test]
    fn the_fast_encoders_write_exactly_prosts_bytes() {
        // Varied shapes: zeros and −0 (omitted), NaN and infinities, empty and long strings
        // (a barrier name that needs a two-byte length), empty lists.
        let long = "o".repeat(300);
        let values = [0.0, -0.0, f64::NAN, f64::INFINITY, -1e300, 3.25, 1e-310];
        let names = |k: usize| -> Vec<String> {
            (0..k)
                .map(|i| if i == 1 { String::new() } else { format!("n{i}") })
                .collect()
        };
        let mut buffer = Vec::new();
        for k in 0..4 {
            let v = |i: usize| values[(k + i) % values.len()];
            let list: Vec<f64> = (0..k).map(v).collect();
            for state in states().into_iter().chain([proto::State {
                time: v(0),
                step: k as u64 * 300,
                names: names(k),
                values: list.clone(),
            }]) {
                buffer.clear();
                encode_state(&state, &mut buffer);
                assert_eq!(buffer, state.encode_to_vec(), "{state:?}");
            }
            let issued = proto::IssuedCommand {
                time: v(1),
                channels: names(k),
                nominal: list.clone(),
                filtered: list.iter().rev().copied().collect(),
            };
            buffer.clear();
            encode_issued(&issued, &mut buffer);
            assert_eq!(buffer, issued.encode_to_vec(), "{issued:?}");
            let applied = proto::AppliedCommand {
                time: v(2),
                channels: names(k),
                values: list.clone(),
                issued_at: list.iter().map(|x| -x).collect(),
            };
            buffer.clear();
            encode_applied(&applied, &mut buffer);
            assert_eq!(buffer, applied.encode_to_vec(), "{applied:?}");
            for (active, infeasible) in [(false, false), (true, false), (false, true), (true, true)] {
                let filter = proto::Filter {
                    time: v(3),
                    active,
                    channels: names(k),
                    correction: list.clone(),
                    infeasible,
                    mu: v(4),
                    unmet: names(k),
                    shortfall: list.clone(),
                    left_out: [0, 1, 300, u32::MAX][k % 4],
                };
                buffer.clear();
                encode_filter(&filter, &mut buffer);
                assert_eq!(buffer, filter.encode_to_vec(), "{filter:?}");
            }
            let barrier = proto::Barrier {
                time: v(5),
                barriers: (0..k)
                    .map(|i| proto::BarrierValue {
                        name: if i == 2 { long.clone() } else { names(k)[i].clone() },
                        h: v(i),
                        constraint: v(i + 1),
                        known: i % 2 == 0,
                        relative_degree: [0, 1, 2, 300][i],
                        clearance: v(i + 2),
                        time_to_collision: v(i + 3),
                        obstacle: i % 3 == 0,
                    })
                    .chain([proto::BarrierValue::default()])
                    .collect(),
            };
            buffer.clear();
            encode_barrier(&barrier, &mut buffer);
            assert_eq!(buffer, barrier.encode_to_vec(), "{barrier:?}");
        }
    }

    #[test]
    fn barrier_records_with_many_values_match_prost() {
        // More values than the encoder keeps lengths of between sizing and writing.
        for count in [7, 8, 9, 20] {
            let barrier = proto::Barrier {
                time: 1.5,
                barriers: (0..count)
                    .map(|i| proto::BarrierValue {
                        name: if i == 9 {
                            "w".repeat(200)
                        } else {
                            format!("obstacle_{i}")
                        },
                        h: i as f64 - 3.0,
                        constraint: -0.5 * i as f64,
                        known: i % 2 == 0,
                        relative_degree: i % 3,
                        clearance: 0.25 * i as f64,
                        time_to_collision: f64::INFINITY,
                        obstacle: i % 4 != 1,
                    })
                    .collect(),
            };
            let mut buffer = vec![7];
            encode_barrier(&barrier, &mut buffer);
            assert_eq!(buffer[1..], barrier.encode_to_vec(), "{count} values");
        }
    }

    #[test]
    fn actor_records_match_prost() {
        for count in [0, 1, 3, 25] {
            let actors = proto::Actors {
                time: [0.0, 2.5, f64::NAN, -0.0][count % 4],
                actors: (0..count)
                    .map(|i| proto::ActorValue {
                        name: match i {
                            0 => String::new(),
                            2 => "é".repeat(80),
                            _ => format!("actor_{i}"),
                        },
                        x: VALUES[i % 8],
                        y: VALUES[(i + 1) % 8],
                        vx: VALUES[(i + 2) % 8],
                        vy: VALUES[(i + 3) % 8],
                        ax: VALUES[(i + 4) % 8],
                        ay: VALUES[(i + 5) % 8],
                        heading: VALUES[(i + 6) % 8],
                        absent: i % 2 == 1,
                    })
                    .collect(),
            };
            let mut buffer = vec![7];
            encode_actors(&actors, &mut buffer);
            assert_eq!(buffer[1..], actors.encode_to_vec(), "{count} road users");
        }
    }

    const VALUES: [f64; 8] = [
        0.0,
        -0.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        3.25,
        -1e300,
        1e-310,
    ];

    /// Scalars cycling through zeros (omitted), −0, NaN, infinities and ordinary values.
    fn v(i: usize) -> f64 {
        VALUES[i % VALUES.len()]
    }

    /// An empty, a short and a 300-byte string.
    fn text(k: usize, short: &str) -> String {
        match k % 3 {
            0 => String::new(),
            1 => short.to_string(),
            _ => "s".repeat(300),
        }
    }

    fn predictions() -> Vec<proto::Prediction> {
        (0..12)
            .map(|k| proto::Prediction {
                time: v(k),
                channel: text(k, "steering"),
                issued_at: v(k + 1),
                horizon: v(k + 2),
                predicted: (0..k % 4).map(|i| v(k + i)).collect(),
                realized: (0..(k + 1) % 4).map(|i| v(k + 3 * i)).collect(),
                error: v(k + 3),
                relative_error: v(k + 4),
                reused_chain: k % 2 == 1,
                chain_mismatch: v(k + 5),
                actors: (0..k % 3).map(|i| text(k + i, "walker")).collect(),
                actor_predicted: (0..2 * (k % 3)).map(|i| v(k + 2 * i)).collect(),
                actor_realized: (0..2 * ((k + 1) % 3)).map(|i| v(k + i + 1)).collect(),
                actor_error: (0..k % 3).map(|i| v(k + i + 6)).collect(),
            })
            .chain([proto::Prediction::default()])
            .collect()
    }

    #[test]
    fn the_prediction_encoder_writes_exactly_prosts_bytes() {
        let mut buffer = Vec::new();
        for m in predictions() {
            buffer.clear();
            encode_prediction(&m, &mut buffer);
            assert_eq!(buffer, m.encode_to_vec(), "{m:?}");
        }
    }

    /// Absent, all zero (an empty body, still written), zero seconds, zero nanoseconds, the
    /// largest.
    fn timestamp(k: usize) -> Option<Timestamp> {
        [
            None,
            Some(Timestamp::MIN),
            Some(Timestamp::new(0, 5)),
            Some(Timestamp::new(7, 0)),
            Some(Timestamp::new(12, 345_000_000)),
            Some(Timestamp::MAX),
        ][k % 6]
    }

    /// As [`timestamp`], and negative seconds (int32: ten bytes).
    fn lifetime(k: usize) -> Option<Duration> {
        [
            None,
            Some(Duration::new(0, 0)),
            Some(Duration::new(0, 5)),
            Some(Duration::new(3, 0)),
            Some(Duration::new(-4, 858_407_346)),
            Some(Duration::MIN),
            Some(Duration::MAX),
        ][k % 7]
    }

    fn vector3(k: usize) -> Option<Vector3> {
        (!k.is_multiple_of(3)).then(|| Vector3 {
            x: v(k),
            y: v(k + 1),
            z: v(k + 2),
        })
    }

    fn quaternion(k: usize) -> Option<Quaternion> {
        (!k.is_multiple_of(4)).then(|| Quaternion {
            x: v(k),
            y: v(k + 3),
            z: v(k + 5),
            w: v(k + 7),
        })
    }

    fn pose(k: usize) -> Option<Pose> {
        (!k.is_multiple_of(5)).then(|| Pose {
            position: vector3(k),
            orientation: quaternion(k + 1),
        })
    }

    fn color(k: usize) -> Color {
        Color {
            r: v(k),
            g: v(k + 2),
            b: v(k + 4),
            a: v(k + 6),
        }
    }

    /// Every line type, and enum values outside it (negative ones take ten bytes).
    fn line(k: usize) -> LinePrimitive {
        use foxglove::messages::line_primitive::Type;
        LinePrimitive {
            r#type: [
                Type::LineStrip as i32,
                Type::LineLoop as i32,
                Type::LineList as i32,
                -1,
                7,
            ][k % 5],
            pose: pose(k),
            thickness: v(k),
            scale_invariant: k.is_multiple_of(2),
            points: (0..k % 6)
                .map(|i| Point3 {
                    x: v(k + i),
                    y: v(k + 2 * i),
                    z: v(i),
                })
                .collect(),
            color: (k % 3 != 1).then(|| color(k)),
            colors: (0..k % 3).map(|i| color(k + i)).collect(),
            indices: (0..k % 5).map(|i| [0, 1, 300, u32::MAX][i % 4]).collect(),
        }
    }

    /// Entities with none, one or several of each field and primitive mjsafe draws.
    fn entity(k: usize) -> SceneEntity {
        SceneEntity {
            timestamp: timestamp(k),
            frame_id: text(k, "world"),
            id: text(k + 1, "vehicle"),
            lifetime: lifetime(k),
            frame_locked: k % 2 == 1,
            metadata: (0..k % 3)
                .map(|i| KeyValuePair {
                    key: text(k + i + 1, "key"),
                    value: text(k + i, "value"),
                })
                .collect(),
            cubes: (0..k % 3)
                .map(|i| CubePrimitive {
                    pose: pose(k + i),
                    size: vector3(k + i + 1),
                    color: (i != 1).then(|| color(k + i)),
                })
                .collect(),
            cylinders: (0..(k + 1) % 4)
                .map(|i| CylinderPrimitive {
                    pose: pose(k + 2 * i),
                    size: vector3(k + i),
                    bottom_scale: v(k + i),
                    top_scale: v(k + i + 1),
                    color: (i != 2).then(|| color(k + 3 * i)),
                })
                .collect(),
            lines: (0..k % 4).map(|i| line(k + i)).collect(),
            ..Default::default()
        }
    }

    fn deletion(k: usize) -> SceneEntityDeletion {
        SceneEntityDeletion {
            timestamp: timestamp(k),
            r#type: [0, 1, -3][k % 3],
            id: text(k, "trail/0"),
        }
    }

    fn assert_scene_as_prost(update: &SceneUpdate) {
        let mut buffer = vec![1, 2, 3];
        buffer.clear();
        encode_scene_update(update, &mut buffer);
        assert!(buffer == update.encode_to_vec(), "{update:?}");
    }

    #[test]
    fn the_scene_and_transform_encoders_write_exactly_prosts_bytes() {
        use crate::log::scene;
        for k in 0..60 {
            assert_scene_as_prost(&SceneUpdate {
                deletions: (0..k % 3).map(|i| deletion(k + i)).collect(),
                entities: (0..k % 4).map(|i| entity(k + i)).collect(),
            });
            let transform = FrameTransform {
                timestamp: timestamp(k),
                parent_frame_id: text(k, "world"),
                child_frame_id: text(k / 3, "vehicle"),
                translation: vector3(k),
                rotation: quaternion(k),
            };
            let mut buffer = Vec::new();
            encode_frame_transform(&transform, &mut buffer);
            assert_eq!(buffer, transform.encode_to_vec(), "{transform:?}");
        }
        // What mjsafe draws.
        let trail: Vec<[f64; 2]> = (0..11).map(|i| [i as f64, 0.5 * i as f64]).collect();
        for update in [
            SceneUpdate::default(),
            scene::vehicle(1.5, [2.0, -3.0], 0.7, 1.2),
            scene::prediction(0.0, "prediction/steering", [0.0, 0.0], [1.0, -0.0], 0.0),
            scene::obstacle(2.75, "obstacle_0", [30.0, 0.5], 1.5, true),
            scene::polyline(12.0, "trail/3", &trail, scene::TRAIL, 0.15),
            scene::polyline(0.0, "reference_path", &[], scene::PATH, 0.1),
        ] {
            assert_scene_as_prost(&update);
        }
    }

    #[test]
    fn nested_lengths_across_the_varint_widths_match_prost() {
        // An entity id or a metadata value of n bytes: the pair, the entity and the update cross
        // 127/128 and 16383/16384 bytes at neighbouring n.
        for n in (0..300).chain(16_300..16_420) {
            let mut e = entity(4);
            e.id = "i".repeat(n);
            assert_scene_as_prost(&SceneUpdate {
                deletions: vec![],
                entities: vec![e.clone()],
            });
            e.id.clear();
            e.metadata = vec![KeyValuePair {
                key: "k".into(),
                value: "v".repeat(n),
            }];
            assert_scene_as_prost(&SceneUpdate {
                deletions: vec![deletion(1)],
                entities: vec![e],
            });
        }
        // A line of 80 000 points: line, entity and update over 2 MB (four-byte lengths).
        let points: Vec<[f64; 2]> = (0..80_000).map(|i| [i as f64, -1.5 * i as f64]).collect();
        assert_scene_as_prost(&crate::log::scene::polyline(
            3.0,
            "trail/0",
            &points,
            Color::default(),
            0.15,
        ));
    }

    #[test]
    fn varint_lengths_match_prost() {
        let mut values: Vec<u64> = vec![0, u64::MAX];
        for bits in 1..64 {
            values.extend([(1u64 << bits) - 1, 1u64 << bits, (1u64 << bits) + 1]);
        }
        for value in values {
            assert_eq!(varint_len(value), prost::encoding::encoded_len_varint(value), "{value}");
        }
    }

    #[test]
    fn submessage_length_prefixes_have_prosts_widths() {
        for length in [0, 1, 127, 128, 129, 16_383, 16_384, 16_385, 2_097_151, 2_097_152] {
            let body = |out: &mut Vec<u8>| out.extend((0..length).map(|i| i as u8));
            let mut expected = vec![9, 9, (3 << 3) | 2];
            prost::encoding::encode_varint(length as u64, &mut expected);
            body(&mut expected);
            for guess in [1, 2] {
                let mut out = vec![9, 9];
                put_message_guessing(&mut out, 3, guess, body);
                assert!(out == expected, "{length}, guessing {guess}");
            }
        }
    }

    #[test]
    fn scene_updates_with_primitives_mjsafe_does_not_draw_go_through_prost() {
        use foxglove::messages::{
            ArrowPrimitive, ModelPrimitive, SpherePrimitive, TextPrimitive, TriangleListPrimitive,
        };
        let mut entities = vec![entity(5); 5];
        entities[0].arrows.push(ArrowPrimitive {
            shaft_length: 2.0,
            color: Some(color(5)),
            ..Default::default()
        });
        entities[1].spheres.push(SpherePrimitive {
            size: vector3(1),
            ..Default::default()
        });
        entities[2].triangles.push(TriangleListPrimitive {
            indices: vec![0, 1, 2],
            ..Default::default()
        });
        entities[3].texts.push(TextPrimitive {
            text: "collision".into(),
            ..Default::default()
        });
        entities[4].models.push(ModelPrimitive {
            url: "file:///car.glb".into(),
            ..Default::default()
        });
        for e in &entities {
            assert!(!hand_encoded(e));
            assert_scene_as_prost(&SceneUpdate {
                deletions: vec![deletion(1)],
                entities: vec![entity(2), e.clone()],
            });
        }
        assert!(hand_encoded(&entity(5)));
    }

    #[test]
    fn encoding_into_a_buffer_with_room_allocates_nothing() {
        use crate::log::{scene, Record};
        use crate::mujoco::counting_alloc::{allocations, count_allocations};
        let trail: Vec<[f64; 2]> = (0..700).map(|i| [i as f64, 0.25 * i as f64]).collect();
        let mut barrier = proto::Barrier {
            time: 1.0,
            barriers: vec![proto::BarrierValue::default(); 3],
        };
        barrier.barriers[1].name = "b".repeat(200);
        let records = [
            Record::Scene(1.0, scene::vehicle(1.0, [1.0, 2.0], 0.5, 1.0)),
            Record::Scene(
                1.0,
                scene::prediction(1.0, "prediction/steering", [1.0, 2.0], [3.0, 2.5], 1.0),
            ),
            // Nested lengths of three bytes.
            Record::Scene(1.0, scene::polyline(1.0, "trail/0", &trail, scene::TRAIL, 0.15)),
            Record::Transform(1.0, scene::transform(1.0, [1.0, 2.0], 0.5)),
            Record::Prediction(predictions()[5].clone()),
            Record::State(states()[0].clone()),
            Record::Barrier(barrier),
        ];
        let mut buffer = Vec::new();
        for record in &records {
            record.encode_into(&mut buffer);
        }
        allocations(true);
        count_allocations(true);
        for record in &records {
            record.encode_into(&mut buffer);
        }
        count_allocations(false);
        assert_eq!(allocations(true), 0);
    }
}

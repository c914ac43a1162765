//! Reading a recording record by record, from the start, as far as its
//! bytes allow: the robot's data is read even from a file that power loss
//! or SIGKILL cut short (no summary, last chunk partial) or whose disk
//! damaged a chunk.
//!
//! The walk frames the records itself, checks each one's length fields
//! (`mcap_bounds`) before the `mcap` crate parses it, decompresses chunks
//! itself (zstd, lz4 or none, as the MCAP specification names them) with
//! the size the chunk declares as the bound, and checks their CRC. A chunk
//! that cannot be read is skipped and named; a record cut off by the end of
//! the file ends the walk there, and [`FileEnd`] says where.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::Path;

use mcap::records::Record;

use super::mcap_bounds::{self, MAGIC, RECORD_HEADER};
use super::RecordingError;

const FOOTER: u8 = 0x02;
const CHUNK: u8 = 0x06;
const DATA_END: u8 = 0x0F;

/// The largest chunk the walk decompresses (the recorder writes 1 MiB
/// chunks; MCAP tools write a few MiB).
const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// How a walk through a recording ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FileEnd {
    /// The data section ended as a closed file's does (its summary follows).
    Complete,
    /// The file stops before its data section's end: it was not closed.
    /// `at` is the byte where the last whole record ends, `reason` what is
    /// there.
    Cut {
        /// Byte offset where the readable part ends.
        at: u64,
        /// What is at that byte, in words.
        reason: String,
    },
}

impl std::fmt::Display for FileEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FileEnd::Complete => write!(f, "complete"),
            FileEnd::Cut { at, reason } => {
                write!(f, "cut off at byte {at} ({reason}): it was not closed")
            }
        }
    }
}

/// What a walk read and what it had to leave out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WalkReport {
    /// Where the readable part of the file ends.
    pub end: FileEnd,
    /// Messages handed over.
    pub messages: u64,
    /// Chunks or records skipped as unreadable.
    pub skipped: Vec<Skipped>,
}

/// A chunk or record the walk could not read and went past.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Skipped {
    /// Byte offset of what is wrong (a length field, a record, a chunk).
    pub at: u64,
    /// What and why.
    pub reason: String,
}

impl std::fmt::Display for Skipped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.reason)
    }
}

impl WalkReport {
    /// Whether the whole file was read (closed, nothing skipped).
    pub fn is_whole(&self) -> bool {
        self.end == FileEnd::Complete && self.skipped.is_empty()
    }
}

/// A channel as its record declared it, with its schema's name and encoding.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// The channel's id in the file.
    pub id: u16,
    /// Topic, e.g. `/cam0`.
    pub topic: String,
    /// `protobuf`, `json`, `cdr`, ...
    pub message_encoding: String,
    /// Channel metadata.
    pub metadata: BTreeMap<String, String>,
    /// The schema's id in the file (0: no schema).
    pub schema_id: u16,
    /// Schema name, e.g. `foxglove.RawImage` (empty without a schema).
    pub schema_name: String,
    /// Schema encoding, e.g. `protobuf`.
    pub schema_encoding: String,
}

/// A schema as its record declared it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaInfo {
    /// The schema's id in the file.
    pub id: u16,
    /// Its name.
    pub name: String,
    /// Its encoding.
    pub encoding: String,
    /// Its data (a descriptor set, a JSON Schema, a message definition).
    pub data: Vec<u8>,
}

/// One message of a recording.
#[derive(Debug)]
pub struct MessageView<'a> {
    /// Its channel.
    pub channel: &'a ChannelInfo,
    /// Sequence number on the channel.
    pub sequence: u32,
    /// Log time, ns.
    pub log_time: u64,
    /// Publish time, ns.
    pub publish_time: u64,
    /// The encoded message.
    pub data: &'a [u8],
}

/// What the walk hands over, in file order.
#[derive(Debug)]
pub enum Item<'a> {
    /// A schema, before any channel that uses it.
    Schema(&'a SchemaInfo),
    /// A channel, before its first message.
    Channel(&'a ChannelInfo),
    /// A message on a channel declared before it.
    Message(MessageView<'a>),
    /// An attachment.
    Attachment {
        /// Its name.
        name: &'a str,
        /// Its media type.
        media_type: &'a str,
        /// Log time, ns.
        log_time: u64,
        /// Creation time, ns.
        create_time: u64,
        /// Its bytes.
        data: &'a [u8],
    },
    /// A metadata record.
    Metadata {
        /// Its name.
        name: &'a str,
        /// Its key-value pairs.
        metadata: &'a BTreeMap<String, String>,
    },
}

/// Walks the records of a recording from its start, calling `f` with each
/// schema, channel, message, attachment and metadata record in file order,
/// until the data section ends, the file ends or `f` breaks. Fails only
/// when `bytes` are not an MCAP file at all.
pub fn walk(
    bytes: &[u8],
    path: &Path,
    mut f: impl FnMut(Item<'_>) -> ControlFlow<()>,
) -> Result<WalkReport, RecordingError> {
    if !bytes.starts_with(MAGIC) {
        return Err(RecordingError::Malformed {
            path: path.to_path_buf(),
            offset: 0,
            reason: "the file does not start with MCAP's magic bytes: not an MCAP file".into(),
        });
    }
    let mut state = State {
        schemas: BTreeMap::new(),
        channels: BTreeMap::new(),
        report: WalkReport {
            end: FileEnd::Complete,
            messages: 0,
            skipped: Vec::new(),
        },
    };
    // A closed file repeats its schemas and channels in its summary: with
    // them known from the start, the messages after a damaged chunk that
    // declared them are still read.
    if mcap_bounds::check(bytes).is_ok() {
        if let Ok(Some(summary)) = mcap::Summary::read(bytes) {
            let mut ids: Vec<u16> = summary.channels.keys().copied().collect();
            ids.sort_unstable();
            for id in ids {
                let channel = &summary.channels[&id];
                if let Some(schema) = &channel.schema {
                    let record = Record::Schema {
                        header: mcap::records::SchemaHeader {
                            id: schema.id,
                            name: schema.name.clone(),
                            encoding: schema.encoding.clone(),
                        },
                        data: Cow::Borrowed(&schema.data),
                    };
                    if let Err(Outcome::Stop) = state.record(record, &mut f) {
                        return Ok(state.report);
                    }
                }
                let record = Record::Channel(mcap::records::Channel {
                    id,
                    schema_id: channel.schema.as_ref().map_or(0, |s| s.id),
                    topic: channel.topic.clone(),
                    message_encoding: channel.message_encoding.clone(),
                    metadata: channel.metadata.clone(),
                });
                if let Err(Outcome::Stop) = state.record(record, &mut f) {
                    return Ok(state.report);
                }
            }
        }
    }
    let mut pos = MAGIC.len();
    loop {
        let left = bytes.len() - pos;
        if left == 0 {
            state.report.end = cut(pos, "the file ends before its data end record");
            break;
        }
        if left < RECORD_HEADER {
            state.report.end = cut(pos, "a record header cut off");
            break;
        }
        let opcode = bytes[pos];
        let len = u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().expect("8 bytes"));
        if len > (left - RECORD_HEADER) as u64 {
            let what = if opcode == CHUNK {
                "a chunk"
            } else {
                "a record"
            };
            state.report.end = cut(
                pos,
                &format!(
                    "{what} of {len} bytes with {} left in the file",
                    left - RECORD_HEADER
                ),
            );
            break;
        }
        let body_at = pos + RECORD_HEADER;
        let body = &bytes[body_at..body_at + len as usize];
        pos = body_at + len as usize;
        match opcode {
            DATA_END | FOOTER => break,
            CHUNK => {
                if state.chunk(body, body_at, &mut f).is_break() {
                    break;
                }
            }
            _ => {
                let record_at = body_at - RECORD_HEADER;
                let problem = |reason: String| {
                    Outcome::Skip(Skipped {
                        at: record_at as u64,
                        reason: format!("record 0x{opcode:02x} at byte {record_at}: {reason}"),
                    })
                };
                let result = mcap_bounds::check_whole_record(opcode, body, body_at)
                    .map_err(|(at, reason)| Outcome::Skip(Skipped { at, reason }))
                    .and_then(|()| {
                        mcap::parse_record(opcode, body).map_err(|e| problem(e.to_string()))
                    })
                    .and_then(|record| {
                        state.record(record, &mut f).map_err(|o| match o {
                            Outcome::Skip(s) => problem(s.reason),
                            stop => stop,
                        })
                    });
                match result {
                    Ok(()) => {}
                    Err(Outcome::Stop) => break,
                    Err(Outcome::Skip(skipped)) => state.report.skipped.push(skipped),
                }
            }
        }
    }
    Ok(state.report)
}

fn cut(at: usize, reason: &str) -> FileEnd {
    FileEnd::Cut {
        at: at as u64,
        reason: reason.to_owned(),
    }
}

/// Why a record was not handed over.
enum Outcome {
    /// `f` asked to stop.
    Stop,
    /// It cannot be read; the walk goes on after it.
    Skip(Skipped),
}

impl From<String> for Outcome {
    fn from(reason: String) -> Self {
        Outcome::Skip(Skipped { at: 0, reason })
    }
}

struct State {
    schemas: BTreeMap<u16, SchemaInfo>,
    channels: BTreeMap<u16, ChannelInfo>,
    report: WalkReport,
}

impl State {
    /// One parsed record (top level or inside a chunk).
    fn record(
        &mut self,
        record: Record<'_>,
        f: &mut impl FnMut(Item<'_>) -> ControlFlow<()>,
    ) -> Result<(), Outcome> {
        let flow = match record {
            Record::Schema { header, data } => {
                if header.id == 0 {
                    return Err("a schema with id 0 (reserved for none)".to_owned().into());
                }
                let schema = SchemaInfo {
                    id: header.id,
                    name: header.name,
                    encoding: header.encoding,
                    data: data.into_owned(),
                };
                // Files repeat schemas (chunks, summary): hand each over once.
                if self.schemas.get(&schema.id) == Some(&schema) {
                    return Ok(());
                }
                let flow = f(Item::Schema(&schema));
                self.schemas.insert(schema.id, schema);
                flow
            }
            Record::Channel(c) => {
                let (schema_name, schema_encoding) = match self.schemas.get(&c.schema_id) {
                    Some(s) => (s.name.clone(), s.encoding.clone()),
                    None if c.schema_id == 0 => (String::new(), String::new()),
                    None => {
                        return Err(format!(
                            "channel {} ({}) names schema {}, which has not been declared",
                            c.id, c.topic, c.schema_id
                        )
                        .into())
                    }
                };
                let channel = ChannelInfo {
                    id: c.id,
                    topic: c.topic,
                    message_encoding: c.message_encoding,
                    metadata: c.metadata,
                    schema_id: c.schema_id,
                    schema_name,
                    schema_encoding,
                };
                if self.channels.get(&channel.id) == Some(&channel) {
                    return Ok(());
                }
                let flow = f(Item::Channel(&channel));
                self.channels.insert(channel.id, channel);
                flow
            }
            Record::Message { header, data } => {
                let Some(channel) = self.channels.get(&header.channel_id) else {
                    return Err(format!(
                        "a message on channel {}, which has not been declared",
                        header.channel_id
                    )
                    .into());
                };
                self.report.messages += 1;
                f(Item::Message(MessageView {
                    channel,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data: &data,
                }))
            }
            Record::Attachment { header, data, .. } => f(Item::Attachment {
                name: &header.name,
                media_type: &header.media_type,
                log_time: header.log_time,
                create_time: header.create_time,
                data: &data,
            }),
            Record::Metadata(m) => f(Item::Metadata {
                name: &m.name,
                metadata: &m.metadata,
            }),
            // Indexes, statistics, the header: nothing to hand over.
            _ => ControlFlow::Continue(()),
        };
        match flow {
            ControlFlow::Continue(()) => Ok(()),
            ControlFlow::Break(()) => Err(Outcome::Stop),
        }
    }

    /// A chunk: decompressed, its CRC checked, its records handed over;
    /// one that cannot be read is skipped whole and named.
    fn chunk(
        &mut self,
        body: &[u8],
        body_at: usize,
        f: &mut impl FnMut(Item<'_>) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        let record_at = body_at - RECORD_HEADER;
        let records = match self.chunk_records(body, body_at) {
            Ok(records) => records,
            Err((at, reason)) => {
                self.report.skipped.push(Skipped {
                    at,
                    reason: format!(
                        "chunk at byte {record_at}: {reason}; its messages are skipped"
                    ),
                });
                return ControlFlow::Continue(());
            }
        };
        // Inner records were checked whole (`check_chunk_records`).
        let mut pos = 0;
        while pos + RECORD_HEADER <= records.len() {
            let opcode = records[pos];
            let len =
                u64::from_le_bytes(records[pos + 1..pos + 9].try_into().expect("8 bytes")) as usize;
            let body = &records[pos + RECORD_HEADER..pos + RECORD_HEADER + len];
            pos += RECORD_HEADER + len;
            let result = mcap::parse_record(opcode, body)
                .map_err(|e| Outcome::from(e.to_string()))
                .and_then(|record| self.record(record, f));
            match result {
                Ok(()) => {}
                Err(Outcome::Stop) => return ControlFlow::Break(()),
                Err(Outcome::Skip(s)) => self.report.skipped.push(Skipped {
                    at: record_at as u64,
                    reason: format!(
                        "record 0x{opcode:02x} in the chunk at byte {record_at}: {}",
                        s.reason
                    ),
                }),
            }
        }
        ControlFlow::Continue(())
    }

    /// The decompressed, CRC-checked and length-checked records of a chunk.
    fn chunk_records<'b>(
        &self,
        body: &'b [u8],
        body_at: usize,
    ) -> Result<Cow<'b, [u8]>, (u64, String)> {
        mcap_bounds::check_whole_record(CHUNK, body, body_at)?;
        let at = (body_at - RECORD_HEADER) as u64;
        self.decompress(body, at).and_then(|records| {
            let data_at = body_at + body.len() - records.1;
            mcap_bounds::check_chunk_records(&records.0, data_at)?;
            Ok(records.0)
        })
    }

    /// The chunk's records decompressed and CRC-checked, and the length of
    /// its (compressed) data.
    fn decompress<'b>(
        &self,
        body: &'b [u8],
        at: u64,
    ) -> Result<(Cow<'b, [u8]>, usize), (u64, String)> {
        let fail = |reason: String| (at, reason);
        let Record::Chunk { header, data } =
            mcap::parse_record(CHUNK, body).map_err(|e| fail(e.to_string()))?
        else {
            unreachable!("a chunk opcode parses into a chunk");
        };
        if header.uncompressed_size > MAX_CHUNK_BYTES {
            return Err(fail(format!(
                "it declares {} uncompressed bytes, more than the {} MiB a chunk may have here",
                header.uncompressed_size,
                MAX_CHUNK_BYTES >> 20
            )));
        }
        let size = header.uncompressed_size as usize;
        let data_len = data.len();
        let records: Cow<'b, [u8]> = match (header.compression.as_str(), data) {
            ("", Cow::Borrowed(d)) => Cow::Borrowed(d),
            ("", Cow::Owned(d)) => Cow::Owned(d),
            ("zstd", d) => Cow::Owned(
                zstd::bulk::decompress(&d, size).map_err(|e| fail(format!("zstd: {e}")))?,
            ),
            ("lz4", d) => {
                let mut out = Vec::with_capacity(size);
                lz4::Decoder::new(&d[..])
                    .and_then(|decoder| decoder.take(size as u64 + 1).read_to_end(&mut out))
                    .map_err(|e| fail(format!("lz4: {e}")))?;
                Cow::Owned(out)
            }
            (other, _) => {
                return Err(fail(format!(
                "compression {other:?} is not one the MCAP specification names (zstd, lz4 or none)"
            )))
            }
        };
        if records.len() != size {
            return Err(fail(format!(
                "{} bytes once decompressed, the chunk declares {size}",
                records.len()
            )));
        }
        if header.uncompressed_crc != 0 {
            let crc = crc32fast::hash(&records);
            if crc != header.uncompressed_crc {
                return Err(fail(format!(
                    "its CRC is {crc:#010x}, the chunk declares {:#010x} (damaged bytes)",
                    header.uncompressed_crc
                )));
            }
        }
        Ok((records, data_len))
    }
}

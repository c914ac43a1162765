//! Rewriting a recording that was cut short (power loss, SIGKILL) or
//! damaged as a closed, indexed MCAP file: every schema, channel,
//! message, attachment and metadata record the [`reader`] recovers, with
//! their times and sequence numbers, chunks compressed with zstd. The
//! original file is never touched; the new one is written atomically.

use std::collections::BTreeMap;
use std::io::Cursor;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use super::reader::{self, Item, WalkReport};
use super::RecordingError;

/// What a repair recovered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Repaired {
    /// The file written.
    pub path: PathBuf,
    /// How far the original could be read, and what was skipped.
    pub source: WalkReport,
    /// Messages written, by topic.
    pub messages: BTreeMap<String, u64>,
    /// Attachments written.
    pub attachments: u64,
}

/// The name a repair writes to by default: `rigslam-000003.mcap` ->
/// `rigslam-000003.repaired.mcap`, beside it.
pub fn repaired_name(path: &Path) -> PathBuf {
    let stem = path
        .file_stem()
        .map_or_else(|| "recording".into(), |s| s.to_string_lossy());
    path.with_file_name(format!("{stem}.repaired.mcap"))
}

/// The profile in the header record that opens an MCAP file (`ros2` for
/// a ROS 2 recording), so that the repaired file keeps it; empty when the
/// header cannot be read.
fn profile_of(bytes: &[u8]) -> &str {
    // Magic (8), opcode 0x01 (1), record length (8), then the profile
    // as a u32 length and its bytes.
    let field = |from: usize, len: usize| bytes.get(from..from.checked_add(len)?);
    let Some([0x01]) = field(8, 1) else {
        return "";
    };
    let len = field(17, 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
    len.and_then(|len| field(21, len))
        .and_then(|b| std::str::from_utf8(b).ok())
        .unwrap_or("")
}

/// Rewrites the recording at `source` into `target` (which must not be
/// `source`).
pub fn repair(source: &Path, target: &Path) -> Result<Repaired, RecordingError> {
    let same = match (source.canonicalize(), target.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    };
    if same {
        return Err(RecordingError::Create {
            path: target.to_path_buf(),
            source: std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "a repair never writes over the file it reads: name another output",
            ),
        });
    }
    let bytes = super::read_bytes(source)?;
    let mcap_err = |source| RecordingError::Mcap {
        path: target.to_path_buf(),
        source,
    };
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(0)
        .profile(profile_of(&bytes))
        .library(concat!("rigslam ", env!("CARGO_PKG_VERSION"), " (repair)"))
        .create(Cursor::new(Vec::new()))
        .map_err(mcap_err)?;
    // Ids in the source -> ids in the new file.
    let mut schemas: BTreeMap<u16, u16> = BTreeMap::new();
    let mut channels: BTreeMap<u16, u16> = BTreeMap::new();
    let mut messages: BTreeMap<String, u64> = BTreeMap::new();
    let mut attachments = 0;
    let mut failure = None;
    let walked = reader::walk(&bytes, source, |item| {
        let result = match item {
            Item::Schema(s) => writer.add_schema(&s.name, &s.encoding, &s.data).map(|id| {
                schemas.insert(s.id, id);
            }),
            Item::Channel(c) => {
                let schema = if c.schema_id == 0 {
                    0
                } else {
                    schemas[&c.schema_id]
                };
                writer
                    .add_channel(schema, &c.topic, &c.message_encoding, &c.metadata)
                    .map(|id| {
                        channels.insert(c.id, id);
                    })
            }
            Item::Message(m) => {
                *messages.entry(m.channel.topic.clone()).or_default() += 1;
                writer.write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: channels[&m.channel.id],
                        sequence: m.sequence,
                        log_time: m.log_time,
                        publish_time: m.publish_time,
                    },
                    m.data,
                )
            }
            Item::Attachment {
                name,
                media_type,
                log_time,
                create_time,
                data,
            } => {
                attachments += 1;
                writer.attach(&mcap::Attachment {
                    log_time,
                    create_time,
                    name: name.to_owned(),
                    media_type: media_type.to_owned(),
                    data: std::borrow::Cow::Borrowed(data),
                })
            }
            Item::Metadata { name, metadata } => writer.write_metadata(&mcap::records::Metadata {
                name: name.to_owned(),
                metadata: metadata.clone(),
            }),
        };
        match result {
            Ok(()) => ControlFlow::Continue(()),
            Err(e) => {
                failure = Some(e);
                ControlFlow::Break(())
            }
        }
    })?;
    if let Some(e) = failure {
        return Err(mcap_err(e));
    }
    writer.finish().map_err(mcap_err)?;
    let out = writer.into_inner().into_inner();
    crate::text_file::write_atomically(target, &out).map_err(|source| RecordingError::Create {
        path: target.to_path_buf(),
        source,
    })?;
    Ok(Repaired {
        path: target.to_path_buf(),
        source: walked,
        messages,
        attachments,
    })
}

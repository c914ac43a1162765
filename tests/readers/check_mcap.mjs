// Reads a rigslam recording with `@mcap/core`, the TypeScript reader
// Foxglove uses, and prints what it found as JSON in the shape
// check_mcap.py prints, so the two readers' findings compare key by key.
//
// Two passes, as in check_mcap.py: McapIndexedReader through the summary
// (its CRC checked) and the chunk indexes, reading every attachment and
// every chunk with the library's CRC checks on; and McapStreamReader from
// the first byte to the last, every record, with its chunk and attachment
// CRCs checked. The data section's CRC, which neither pass checks, is
// computed here over the streamed bytes. Chunks are decompressed by
// Foxglove's WebAssembly zstd and lz4 decoders. Every message of both
// passes is decoded with protobufjs through the FileDescriptorSet its
// schema carries, and both passes must decode the same values.
//
// Numbers are printed as Python's json module prints what check_mcap.py
// decodes: protobuf integers (64-bit ones exactly) as integers, doubles
// and floats with a decimal point or an exponent in Python's repr form.
//
// The packages come from the directory RIGSLAM_JS names (its
// node_modules, installed from this directory's package-lock.json by
// scripts/test), or from this directory when it is unset.
//
// Usage: node check_mcap.mjs FILE.mcap

import { createReadStream } from "node:fs";
import { open } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const packages = path.resolve(
  process.env.RIGSLAM_JS || path.dirname(fileURLToPath(import.meta.url)),
);
const require = createRequire(path.join(packages, "package.json"));
const { McapIndexedReader, McapStreamReader } = require("@mcap/core");
const { crc32, crc32Init, crc32Update, crc32Final } = require("@foxglove/crc");
const zstd = require("@foxglove/wasm-zstd");
const lz4 = require("@foxglove/wasm-lz4");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

/** Decompressors that also insist on the size the chunk announces. */
function decompressHandlers() {
  const exact = (name, decompress) => (data, size) => {
    const out = decompress(data, Number(size));
    if (BigInt(out.byteLength) !== BigInt(size)) {
      throw new Error(`${name} chunk: ${out.byteLength} bytes, not the ${size} announced`);
    }
    return out;
  };
  return { zstd: exact("zstd", zstd.decompress), lz4: exact("lz4", lz4) };
}

/** A double or float field's value, printed as Python prints a float. */
class Float {
  constructor(value) {
    this.value = value;
  }
}

/** Python's repr of a float: shortest round-trip digits, exponent form
 * below 1e-4 and from 1e16 on, ".0" on integral values. */
function pythonFloat(x) {
  if (Number.isNaN(x)) return "NaN";
  if (x === Infinity) return "Infinity";
  if (x === -Infinity) return "-Infinity";
  const sign = x < 0 || Object.is(x, -0) ? "-" : "";
  const [mantissa, exp] = Math.abs(x).toExponential().split("e");
  const digits = mantissa.replace(".", "");
  const e = Number(exp);
  if (e < -4 || e >= 16) {
    const frac = digits.length > 1 ? `.${digits.slice(1)}` : "";
    const es = e < 0 ? "-" : "+";
    return `${sign}${digits[0]}${frac}e${es}${String(Math.abs(e)).padStart(2, "0")}`;
  }
  if (e < 0) return `${sign}0.${"0".repeat(-e - 1)}${digits}`;
  const whole = digits.slice(0, e + 1).padEnd(e + 1, "0");
  const frac = digits.slice(e + 1);
  return `${sign}${whole}.${frac || "0"}`;
}

/** JSON as Python's json.dump writes it (", " and ": ", ASCII only). */
function pythonJson(v) {
  if (v === null) return "null";
  if (v instanceof Float) return pythonFloat(v.value);
  if (typeof v === "bigint") return v.toString();
  if (typeof v === "number") {
    if (!Number.isSafeInteger(v)) throw new Error(`untyped non-integer number ${v}`);
    return String(v);
  }
  if (typeof v === "boolean") return String(v);
  if (typeof v === "string") {
    return JSON.stringify(v).replace(
      /[\u0080-\uffff]/g,
      (c) => `\\u${c.charCodeAt(0).toString(16).padStart(4, "0")}`,
    );
  }
  if (Array.isArray(v)) return `[${v.map(pythonJson).join(", ")}]`;
  if (typeof v === "object") {
    const items = Object.entries(v).map(([k, x]) => `${pythonJson(k)}: ${pythonJson(x)}`);
    return `{${items.join(", ")}}`;
  }
  throw new Error(`cannot print ${typeof v}`);
}

const FLOATS = new Set(["double", "float"]);
const INTEGERS = new Set([
  "int32", "uint32", "sint32", "fixed32", "sfixed32",
  "int64", "uint64", "sint64", "fixed64", "sfixed64",
]);

/** One scalar of `field` as Python's protobuf gives it. */
function scalar(field, x) {
  if (FLOATS.has(field.type)) return new Float(x);
  if (INTEGERS.has(field.type)) return BigInt(typeof x === "number" ? x : x.toString());
  if (field.resolvedType instanceof protobuf.Enum) return BigInt(x);
  if (field.type === "string" || field.type === "bytes" || field.type === "bool") return x;
  if (field.resolvedType instanceof protobuf.Type) {
    return x ?? field.resolvedType.create(); // an unset message reads as its defaults
  }
  throw new Error(`field ${field.fullName}: type ${field.type}`);
}

/** Field `name` of decoded message `m`, looked up in its schema: a typo
 * or a renamed field fails here rather than reading as undefined. */
function get(m, name) {
  const field = m.$type.fields[name];
  if (!field) throw new Error(`${m.$type.fullName} has no field ${name}`);
  field.resolve();
  const v = m[name];
  return field.repeated ? v.map((x) => scalar(field, x)) : scalar(field, v);
}

/** The values check_mcap.py's fields() takes from each message, in its order. */
function fields(topic, m) {
  if (topic === "/imu0") {
    return [get(m, "t_ns"), ...get(m, "gyro_rad_s"), ...get(m, "accel_m_s2")];
  }
  if (topic === "/cam0" || topic === "/cam1") {
    const stamp = get(m, "timestamp");
    return [
      get(stamp, "seconds"),
      get(stamp, "nanos"),
      get(m, "width"),
      get(m, "height"),
      get(m, "step"),
      get(m, "encoding"),
      get(m, "frame_id"),
      BigInt(crc32(get(m, "data"))),
    ];
  }
  if (topic === "/rigslam/pose") {
    return [
      get(m, "t_ns"),
      get(m, "tracking_state"),
      get(m, "flags"),
      ...get(m, "position_world_m"),
      ...get(m, "orientation_world_body_xyzw"),
      ...get(m, "position_odom_m"),
      ...get(m, "translation_world_odom_m"),
      BigInt(get(m, "covariance").length),
    ];
  }
  if (topic === "/rigslam/pose_map" || topic === "/rigslam/pose_odom") {
    const stamp = get(m, "timestamp");
    const p = get(get(m, "pose"), "position");
    return [
      get(m, "frame_id"),
      get(stamp, "seconds"),
      get(stamp, "nanos"),
      get(p, "x"),
      get(p, "y"),
      get(p, "z"),
    ];
  }
  if (topic === "/tf") {
    return get(m, "transforms").map((t) => [get(t, "parent_frame_id"), get(t, "child_frame_id")]);
  }
  if (topic.endsWith("/calibration")) {
    return [
      get(m, "frame_id"),
      get(m, "width"),
      get(m, "height"),
      get(m, "distortion_model"),
      get(m, "K"),
      get(m, "D"),
    ];
  }
  if (topic === "/rigslam/status") {
    return [get(m, "t_ns"), get(m, "health"), get(m, "camera_rate_hz")];
  }
  return null;
}

/** Decodes messages through the descriptors their schemas carry. */
class Decoder {
  #types = new Map();

  decode(schema, channel, data) {
    let type = this.#types.get(schema);
    if (!type) {
      if (schema.encoding !== "protobuf" || channel.messageEncoding !== "protobuf") {
        throw new Error(`${channel.topic}: schema ${schema.encoding}, message ${channel.messageEncoding}`);
      }
      const set = descriptor.FileDescriptorSet.decode(schema.data);
      const root = protobuf.Root.fromDescriptor(set);
      root.resolveAll();
      type = root.lookupType(schema.name);
      this.#types.set(schema, type);
    }
    return type.decode(data);
  }
}

/** A range of the file for McapIndexedReader. */
function readable(handle, size) {
  return {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buffer = new Uint8Array(Number(length));
      const { bytesRead } = await handle.read(buffer, 0, buffer.length, Number(offset));
      if (bytesRead !== buffer.length) throw new Error(`short read at ${offset}`);
      return buffer;
    },
  };
}

function push(map, key, value) {
  if (!(key in map)) map[key] = [];
  map[key].push(value);
}

async function indexedPass(file, out) {
  const handle = await open(file, "r");
  try {
    const { size } = await handle.stat();
    const reader = await McapIndexedReader.Initialize({
      readable: readable(handle, size),
      decompressHandlers: decompressHandlers(),
    });
    if (!reader.statistics) throw new Error(`${file}: no statistics in the summary`);
    out.statistics_messages = reader.statistics.messageCount;
    out.chunk_indexes = reader.chunkIndexes.length;
    out.chunk_compression = [...new Set(reader.chunkIndexes.map((c) => c.compression))].sort();
    out.attachments = reader.attachmentIndexes.map((a) => a.name).sort();
    let attachments = 0;
    for await (const a of reader.readAttachments({ validateCrcs: true })) {
      if (!out.attachments.includes(a.name)) throw new Error(`attachment ${a.name} not indexed`);
      attachments += 1;
    }
    if (attachments !== out.attachments.length) {
      throw new Error(`${attachments} attachments read, ${out.attachments.length} indexed`);
    }
    out.metadata = {};
    for await (const m of reader.readMetadata()) {
      out.metadata[m.name] = Object.fromEntries(m.metadata);
    }
    const decoder = new Decoder();
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const channel = reader.channelsById.get(message.channelId);
      const schema = reader.schemasById.get(channel.schemaId);
      const topic = channel.topic;
      out.messages[topic] = (out.messages[topic] ?? 0) + 1;
      push(out.values, topic, fields(topic, decoder.decode(schema, channel, message.data)));
      push(out.log_times, topic, message.logTime);
    }
    return { dataEndOffset: reader.dataEndOffset, dataSectionCrc: reader.dataSectionCrc };
  } finally {
    await handle.close();
  }
}

/** Every record from the first byte to the last; the decoded values by topic. */
async function streamedPass(file, dataEnd) {
  const reader = new McapStreamReader({ decompressHandlers: decompressHandlers(), validateCrcs: true });
  const schemas = new Map();
  const channels = new Map();
  const decoder = new Decoder();
  const values = {};
  let streamed = 0;
  let offset = 0n;
  let crc = crc32Init();
  let dataEndCrc;
  let footer = false;
  for await (const piece of createReadStream(file, { highWaterMark: 1 << 20 })) {
    if (offset < dataEnd.dataEndOffset) {
      const inData = Number(dataEnd.dataEndOffset - offset);
      crc = crc32Update(crc, piece.subarray(0, Math.min(inData, piece.length)));
    }
    offset += BigInt(piece.length);
    reader.append(piece);
    for (let record; (record = reader.nextRecord()); ) {
      switch (record.type) {
        case "Schema":
          schemas.set(record.id, record);
          break;
        case "Channel":
          channels.set(record.id, record);
          break;
        case "Message": {
          const channel = channels.get(record.channelId);
          if (!channel) throw new Error(`message on unknown channel ${record.channelId}`);
          const schema = schemas.get(channel.schemaId);
          if (!schema) throw new Error(`${channel.topic}: unknown schema ${channel.schemaId}`);
          streamed += 1;
          push(values, channel.topic, fields(channel.topic, decoder.decode(schema, channel, record.data)));
          break;
        }
        case "DataEnd":
          dataEndCrc = record.dataSectionCrc;
          break;
        case "Footer":
          footer = true;
          break;
        default:
          break;
      }
    }
  }
  if (!footer || !reader.done()) throw new Error(`${file}: the stream ended before the footer`);
  if (dataEndCrc === undefined) throw new Error(`${file}: no DataEnd record`);
  if (dataEndCrc !== (dataEnd.dataSectionCrc ?? 0)) {
    throw new Error(`DataEnd CRC ${dataEndCrc} streamed, ${dataEnd.dataSectionCrc} indexed`);
  }
  if (dataEndCrc !== 0 && crc32Final(crc) !== dataEndCrc) {
    throw new Error(`data section CRC ${crc32Final(crc)} (expected ${dataEndCrc})`);
  }
  return { streamed, values };
}

async function main(file) {
  await Promise.all([zstd.isLoaded, lz4.isLoaded]);
  const out = { messages: {}, values: {}, log_times: {} };
  const dataEnd = await indexedPass(file, out);
  const { streamed, values } = await streamedPass(file, dataEnd);
  out.streamed_messages = streamed;
  // Both passes decoded the same values, topic by topic.
  if (pythonJson(sortedKeys(out.values)) !== pythonJson(sortedKeys(values))) {
    throw new Error(`${file}: the streamed messages differ from the indexed ones`);
  }
  process.stdout.write(pythonJson(out));
}

function sortedKeys(o) {
  return Object.fromEntries(Object.entries(o).sort(([a], [b]) => (a < b ? -1 : a > b ? 1 : 0)));
}

main(process.argv[2]).catch((e) => {
  console.error(e?.stack ?? e);
  process.exit(1);
});

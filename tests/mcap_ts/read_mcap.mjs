// Read an MCAP file with the official TypeScript reader (@mcap/core, the library Foxglove and
// Lichtblick use for local files) and print what it saw as one JSON object on stdout.
//
//   node read_mcap.mjs FILE.mcap [--count KEY]...
//
// Both readers Foxglove uses are run: McapIndexedReader (seeks through the summary, chunk
// indexes and message indexes: what opening a local file does) and McapStreamReader (reads
// record by record from the start: what a stream or a remote file without a summary gets).
// Decompression (zstd, lz4, bz2) comes from @mcap/support. Every message is parsed with
// JSON.parse, as Foxglove does for the "json" message encoding; with --count KEY, the values
// of that top-level key are counted per topic ("values": {topic: {KEY: {value: n}}}; a
// missing key counts as "<absent>"). The indexed reader that throws reports {"error": "..."}
// instead of its counts; the stream reader keeps what it read before the error (a file cut
// by a crash: "done" false, "error" set). The script always exits 0 with one JSON line
// unless it is called wrongly (exit 2).
import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";

const countKeys = [];

function newSummary() {
  return {
    values: {}, // topic -> key -> value -> count (the --count keys)
    topics: {}, // topic -> message count
    schemas: {}, // topic -> schema name
    schema_encodings: {}, // topic -> schema encoding
    message_encodings: {}, // topic -> message encoding
    metadata: [], // metadata record names, in file order
    json_errors: 0, // messages JSON.parse refused
    messages: 0,
    first_log_time: null, // ns, as a decimal string (a bigint)
    last_log_time: null,
    out_of_order: 0, // messages whose log_time is before the previous one
  };
}

function countMessage(out, channel, schema, message) {
  const topic = channel.topic;
  out.topics[topic] = (out.topics[topic] ?? 0) + 1;
  out.schemas[topic] = schema ? schema.name : "";
  out.schema_encodings[topic] = schema ? schema.encoding : "";
  out.message_encodings[topic] = channel.messageEncoding;
  out.messages += 1;
  if (channel.messageEncoding === "json") {
    let payload;
    try {
      payload = JSON.parse(new TextDecoder().decode(message.data));
    } catch {
      out.json_errors += 1;
    }
    if (payload !== undefined && countKeys.length > 0) {
      const byKey = (out.values[topic] ??= {});
      for (const key of countKeys) {
        const value = key in payload ? JSON.stringify(payload[key]) : "<absent>";
        const counts = (byKey[key] ??= {});
        counts[value] = (counts[value] ?? 0) + 1;
      }
    }
  }
  const t = message.logTime;
  if (out.last_log_time !== null && t < BigInt(out.last_log_time)) out.out_of_order += 1;
  if (out.first_log_time === null) out.first_log_time = t.toString();
  out.last_log_time = t.toString();
}

async function readIndexed(path, decompressHandlers) {
  const handle = await open(path, "r");
  try {
    const readable = {
      size: async () => BigInt((await handle.stat()).size),
      read: async (offset, length) => {
        const buffer = new Uint8Array(Number(length));
        const { bytesRead } = await handle.read(buffer, 0, Number(length), Number(offset));
        if (bytesRead !== Number(length)) throw new Error(`short read at ${offset}`);
        return buffer;
      },
    };
    const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    const out = newSummary();
    out.library = reader.header.library;
    out.profile = reader.header.profile;
    out.chunk_indexes = reader.chunkIndexes.length;
    out.chunk_indexes_without_message_indexes = reader.chunkIndexes.filter(
      (c) => c.messageIndexOffsets.size === 0,
    ).length;
    out.statistics_message_count =
      reader.statistics === undefined ? null : reader.statistics.messageCount.toString();
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const channel = reader.channelsById.get(message.channelId);
      countMessage(out, channel, reader.schemasById.get(channel.schemaId), message);
    }
    for await (const meta of reader.readMetadata()) out.metadata.push(meta.name);
    return out;
  } finally {
    await handle.close();
  }
}

async function readStream(path, decompressHandlers) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  const out = newSummary();
  const schemas = new Map();
  const channels = new Map();
  reader.append(new Uint8Array(await readFile(path)));
  try {
    readRecords(reader, out, schemas, channels);
  } catch (err) {
    out.error = String(err && err.message ? err.message : err);
  }
  out.done = reader.done(); // a complete file: the footer and closing magic were read
  out.bytes_remaining = reader.bytesRemaining();
  return out;
}

function readRecords(reader, out, schemas, channels) {
  for (let record; (record = reader.nextRecord()); ) {
    switch (record.type) {
      case "Header":
        out.library = record.library;
        out.profile = record.profile;
        break;
      case "Schema":
        schemas.set(record.id, record);
        break;
      case "Channel":
        channels.set(record.id, record);
        break;
      case "Message": {
        const channel = channels.get(record.channelId);
        countMessage(out, channel, schemas.get(channel.schemaId), record);
        break;
      }
      case "Metadata":
        out.metadata.push(record.name);
        break;
      default:
        break;
    }
  }
}

async function guarded(fn) {
  try {
    return await fn();
  } catch (err) {
    return { error: String(err && err.message ? err.message : err) };
  }
}

const args = process.argv.slice(2);
let path = null;
for (let i = 0; i < args.length; i++) {
  if (args[i] === "--count" && i + 1 < args.length) countKeys.push(args[++i]);
  else if (path === null && !args[i].startsWith("--")) path = args[i];
  else path = undefined;
}
if (!path) {
  console.error("usage: node read_mcap.mjs FILE.mcap [--count KEY]...");
  process.exit(2);
}
const decompressHandlers = await loadDecompressHandlers();
const result = {
  file: path,
  indexed: await guarded(() => readIndexed(path, decompressHandlers)),
  stream: await guarded(() => readStream(path, decompressHandlers)),
};
process.stdout.write(JSON.stringify(result) + "\n");

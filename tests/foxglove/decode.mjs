// Decode MCAP files the way the Foxglove app does, and report what it could not read.
//
//   node decode.mjs FILE.mcap [FILE.mcap ...]
//
// For each file: the indexed reader of @mcap/core (zstd chunks through @foxglove/wasm-zstd),
// every `ros2msg` schema parsed by @foxglove/rosmsg (`parse(text, {ros2: true})`, as the app's
// ROS 2 message decoder does) and every message read with @foxglove/rosmsg2-serialization's
// MessageReader. A message counts as decoded only if the reader consumed all of its bytes but
// CDR's final alignment padding (< 4 bytes): leftover bytes mean schema and payload disagree.
// Every model embedded in a foxglove_msgs/msg/SceneUpdate (what the 3D panel draws) must be
// glTF binary that the Khronos glTF validator (gltf-validator) passes without errors.
//
// Prints one JSON document on stdout:
//   {"FILE": {"schemas": {NAME: {"ok": bool, "error"?: str}},
//             "topics": {TOPIC: {"schema": NAME, "decoded": n, "failed": n, "error"?: str,
//                                "fields"?: [top-level field names], "max"?: {numeric field: largest value},
//                                "models"?: n}}}}
// and exits 1 when any schema or message failed, 2 on a file that cannot be read at all.

import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import * as zstd from "@foxglove/wasm-zstd";
import validator from "gltf-validator";

// Alignment padding a CDR writer may leave after the last field.
const MAX_PADDING = 3;

const SCENE_UPDATE = "foxglove_msgs/msg/SceneUpdate";
const GLB = "model/gltf-binary";

// Throws unless every embedded model of a decoded SceneUpdate is valid glTF binary; returns their count.
async function checkModels(sceneUpdate) {
  let count = 0;
  for (const entity of sceneUpdate.entities) {
    for (const model of entity.models) {
      if (model.url !== "") {
        throw new Error(`entity ${entity.id} loads its model from ${model.url}, not from the log`);
      }
      if (model.media_type !== GLB) {
        throw new Error(`entity ${entity.id} model has media type ${model.media_type}, not ${GLB}`);
      }
      const report = await validator.validateBytes(new Uint8Array(model.data), { maxIssues: 5 });
      if (report.issues.numErrors > 0) {
        const first = report.issues.messages.map((m) => `${m.code}: ${m.message}`).join("; ");
        throw new Error(`entity ${entity.id} model is not valid glTF: ${first}`);
      }
      count += 1;
    }
  }
  return count;
}

async function readableFile(path) {
  const handle = await open(path, "r");
  const { size } = await handle.stat();
  return {
    handle,
    readable: {
      size: async () => BigInt(size),
      read: async (offset, length) => {
        const buffer = new Uint8Array(Number(length));
        await handle.read(buffer, 0, buffer.length, Number(offset));
        return buffer;
      },
    },
  };
}

async function decodeFile(path) {
  const { handle, readable } = await readableFile(path);
  try {
    const reader = await McapIndexedReader.Initialize({
      readable,
      decompressHandlers: { zstd: (data, size) => zstd.decompress(data, Number(size)) },
    });
    const schemas = {};
    const readers = new Map(); // schema id -> MessageReader
    for (const schema of reader.schemasById.values()) {
      if (schema.encoding !== "ros2msg") {
        schemas[schema.name] = { ok: false, error: `schema encoding ${schema.encoding}, not ros2msg` };
        continue;
      }
      try {
        const text = new TextDecoder().decode(schema.data);
        readers.set(schema.id, new MessageReader(parse(text, { ros2: true })));
        schemas[schema.name] = { ok: true };
      } catch (e) {
        schemas[schema.name] = { ok: false, error: String(e.message ?? e) };
      }
    }
    const topics = {};
    for (const channel of reader.channelsById.values()) {
      const schema = reader.schemasById.get(channel.schemaId);
      topics[channel.topic] = { schema: schema?.name ?? null, decoded: 0, failed: 0 };
    }
    for await (const message of reader.readMessages()) {
      const channel = reader.channelsById.get(message.channelId);
      const entry = topics[channel.topic];
      const messageReader = readers.get(channel.schemaId);
      if (channel.messageEncoding !== "cdr" || messageReader === undefined) {
        entry.failed += 1;
        entry.error ??= channel.messageEncoding !== "cdr"
          ? `message encoding ${channel.messageEncoding}, not cdr` : "schema did not parse";
        continue;
      }
      try {
        const decoded = messageReader.readMessage(message.data);
        const left = message.data.byteLength - messageReader.lastReadByteLength();
        if (typeof decoded !== "object" || decoded === null) {
          throw new Error("decoded to no object");
        }
        if (left > MAX_PADDING) {
          throw new Error(`${left} of ${message.data.byteLength} bytes left after decoding`);
        }
        // the top-level fields as decoded, and the largest value of each numeric one (a NaN
        // makes it NaN, written as null): the test sees the fields and values Foxglove reads
        entry.fields ??= Object.keys(decoded);
        entry.max ??= {};
        for (const [key, value] of Object.entries(decoded)) {
          if (typeof value === "number") {
            entry.max[key] = Math.max(entry.max[key] ?? -Number.MAX_VALUE, value);
          }
        }
        if (reader.schemasById.get(channel.schemaId).name === SCENE_UPDATE) {
          entry.models = (entry.models ?? 0) + (await checkModels(decoded));
        }
        entry.decoded += 1;
      } catch (e) {
        entry.failed += 1;
        entry.error ??= String(e.message ?? e);
      }
    }
    return { schemas, topics };
  } finally {
    await handle.close();
  }
}

async function main(paths) {
  if (paths.length === 0) {
    process.stderr.write("usage: node decode.mjs FILE.mcap [FILE.mcap ...]\n");
    return 2;
  }
  await zstd.isLoaded;
  const report = {};
  let failed = false;
  for (const path of paths) {
    try {
      report[path] = await decodeFile(path);
    } catch (e) {
      process.stderr.write(`${path}: cannot read: ${e.message ?? e}\n`);
      return 2;
    }
    const { schemas, topics } = report[path];
    failed ||= Object.values(schemas).some((s) => !s.ok) || Object.values(topics).some((t) => t.failed > 0);
  }
  process.stdout.write(JSON.stringify(report, null, 1) + "\n");
  return failed ? 1 : 0;
}

process.exitCode = await main(process.argv.slice(2));

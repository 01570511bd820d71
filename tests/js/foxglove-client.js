#!/usr/bin/env node
// Foxglove's own WebSocket client library (@foxglove/ws-protocol) against a mouthpiece server:
// lists the advertised channels, subscribes to every one, and checks each message against
// Foxglove's published JSON Schema of its schema name (@foxglove/schemas, validated with ajv;
// a field the schema does not have is an error too); mouthpiece's own channels are checked
// the same way against the JSON Schema the server advertises for them. Prints one JSON
// summary on stdout.
//
//     node foxglove-client.js ws://127.0.0.1:9870/ SECONDS
"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const foxgloveSchemas = require("@foxglove/schemas/jsonschema");
const Ajv = require("ajv");

const [url, secondsArg] = process.argv.slice(2);
const seconds = Number(secondsArg || "3");

const ajv = new Ajv({ strict: false, allErrors: true });
const validators = {};
function validatorFor(channel) {
  const { schemaName } = channel;
  const short = schemaName.replace(/^foxglove\./, "");
  if (schemaName.startsWith("foxglove.") && foxgloveSchemas[short]) {
    if (!validators[short]) validators[short] = ajv.compile(foxgloveSchemas[short]);
    return { validate: validators[short], schema: foxgloveSchemas[short] };
  }
  if (channel.schemaEncoding !== "jsonschema") return null;
  // A channel of our own: its advertised schema.
  const key = `${channel.id}:${channel.schema}`;
  if (!validators[key]) {
    const schema = safeParse(channel.schema);
    try {
      validators[key] = { validate: ajv.compile(schema), schema };
    } catch (e) {
      problem(`${channel.topic}: advertised schema does not compile: ${e.message}`);
      validators[key] = null;
    }
  }
  return validators[key];
}

// Fields of `value` that `schema` does not list (JSON Schema allows them; Foxglove would
// ignore them, so a misspelt field would silently draw nothing).
function unknownFields(schema, value, path, out) {
  if (!schema || value === null || typeof value !== "object") return;
  if (Array.isArray(value)) {
    value.forEach((v, i) => unknownFields(schema.items, v, `${path}[${i}]`, out));
    return;
  }
  const props = schema.properties || {};
  for (const [k, v] of Object.entries(value)) {
    if (!(k in props)) out.push(`${path}.${k}`);
    else unknownFields(props[k], v, `${path}.${k}`, out);
  }
}

const summary = { channels: [], messages: {}, samples: {}, problems: [], statuses: [] };
const problems = new Set();
const problem = (text) => problems.add(text);
const client = new FoxgloveClient({
  ws: new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
const byChannel = new Map();
const bySubscription = new Map();
const decoder = new TextDecoder();

client.on("advertise", (channels) => {
  for (const c of channels) {
    byChannel.set(c.id, c);
    summary.channels.push({ id: c.id, topic: c.topic, encoding: c.encoding, schemaName: c.schemaName,
      schemaEncoding: c.schemaEncoding, schemaTitle: safeParse(c.schema).title || null });
    const sub = client.subscribe(c.id);
    bySubscription.set(sub, c);
  }
});
client.on("status", (s) => summary.statuses.push(s));
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const channel = bySubscription.get(subscriptionId);
  if (!channel) { problem(`message for unknown subscription ${subscriptionId}`); return; }
  const text = decoder.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  let message;
  try { message = JSON.parse(text); } catch (e) {
    problem(`${channel.topic}: not JSON: ${e.message}`); return;
  }
  summary.messages[channel.topic] = (summary.messages[channel.topic] || 0) + 1;
  summary.samples[channel.topic] = message;
  const checker = validatorFor(channel);
  if (checker) {
    const { validate, schema } = checker;
    if (!validate(message)) {
      problem(`${channel.topic}: ${ajv.errorsText(validate.errors)}`);
    }
    const extra = [];
    unknownFields(schema, message, "", extra);
    if (extra.length) problem(`${channel.topic}: fields not in ${channel.schemaName}: ${extra.slice(0, 5).join(", ")}`);
  }
  if (typeof timestamp !== "bigint" || timestamp <= 0n) {
    problem(`${channel.topic}: bad timestamp ${timestamp}`);
  }
});
client.on("error", (e) => problem(`error: ${e && e.message}`));

function safeParse(text) {
  try { return JSON.parse(text); } catch { return {}; }
}

setTimeout(() => {
  // Sample images are large; keep their size only.
  const image = summary.samples["/camera/image"];
  if (image && typeof image.data === "string") {
    const bytes = Buffer.from(image.data, "base64");
    image.data = { base64_bytes: bytes.length, starts: bytes.slice(0, 2).toString("hex") };
  }
  summary.problems = [...problems];
  process.stdout.write(JSON.stringify(summary) + "\n");
  client.close();
  process.exit(0);
}, seconds * 1000);

// Foxglove's own client, FoxgloveClient (npm @foxglove/ws-protocol), as Foxglove's app uses it:
// a `ws` WebSocket offering the client's default subprotocol, every advertised channel
// subscribed, every message decoded with the schema the server advertised (protobuf through
// protobufjs's descriptor support, JSON as text). Prints one JSON summary line and exits once
// every topic in argv[3] (comma-separated) has had a message, or after argv[4] seconds.
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const protobuf = require("protobufjs");
const descriptor = require("protobufjs/ext/descriptor");

const [url, wanted, seconds] = [process.argv[2], process.argv[3].split(","), Number(process.argv[4] || 60)];
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const out = { offered: FoxgloveClient.SUPPORTED_SUBPROTOCOL, protocol: null, serverInfo: null, channels: [],
              counts: {}, first: {}, last: {}, errors: [] };
const bySubscription = new Map();

function decoderFor(channel) {
  if (channel.encoding === "json") {
    if (channel.schemaEncoding !== "jsonschema" || !JSON.parse(channel.schema).properties) {
      throw new Error(`${channel.topic}: a JSON channel without a JSON schema`);
    }
    const text = new TextDecoder();
    return (data) => JSON.parse(text.decode(data));
  }
  if (channel.encoding !== "protobuf" || channel.schemaEncoding !== "protobuf") {
    throw new Error(`${channel.topic}: encoding ${channel.encoding} / ${channel.schemaEncoding}`);
  }
  const set = descriptor.FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
  const type = protobuf.Root.fromDescriptor(set).lookupType(channel.schemaName);
  return (data) => type.toObject(type.decode(data), { longs: Number, bytes: String, defaults: true });
}

function finish() {
  ws.removeAllListeners();
  process.stdout.write(JSON.stringify(out) + "\n", () => process.exit(0));
}

ws.on("open", () => { out.protocol = ws.protocol; });
client.on("error", (err) => out.errors.push(String(err && err.message ? err.message : err)));
client.on("serverInfo", (info) => { out.serverInfo = info; });
client.on("advertise", (channels) => {
  for (const channel of channels) {
    out.channels.push({ id: channel.id, topic: channel.topic, encoding: channel.encoding,
                        schemaName: channel.schemaName, schemaEncoding: channel.schemaEncoding });
    try {
      const decode = decoderFor(channel);
      bySubscription.set(client.subscribe(channel.id), { topic: channel.topic, decode });
    } catch (err) {
      out.errors.push(String(err.message));
    }
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const sub = bySubscription.get(subscriptionId);
  if (sub === undefined) {
    out.errors.push(`a message for subscription ${subscriptionId}, never made`);
    return;
  }
  let message;
  try {
    message = sub.decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));  // data: a DataView
  } catch (err) {
    out.errors.push(`${sub.topic}: ${err.message}`);
    return;
  }
  out.counts[sub.topic] = (out.counts[sub.topic] || 0) + 1;
  if (!(sub.topic in out.first)) out.first[sub.topic] = message;
  out.last[sub.topic] = message;
  if (wanted.every((topic) => out.counts[topic] > 0)) finish();
});
client.on("close", () => finish());
setTimeout(finish, seconds * 1000);

// A Foxglove WebSocket client that is not the project's: Foxglove's own ws-protocol client,
// its ros2msg parser and its CDR reader. Usage: node client.js URL MIN TOPIC [TOPIC ...]
// Subscribes to every advertised channel whose topic ends with one of TOPIC, decodes each
// message with the channel's own schema, and exits 0 once every TOPIC has MIN decoded
// messages; 1 when a message does not decode, a field is not a finite number, or nothing
// (enough) arrives within 120 s (the timeout is not armed when MIN is 0: it decodes until
// SIGTERM). Prints one JSON line: messages decoded per topic, samples, and the milliseconds
// from its subscription to each topic's first message (first_ms).
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");
const WebSocket = require("ws");

const [url, minText, ...wanted] = process.argv.slice(2);
const min = Number(minText);
const counts = Object.fromEntries(wanted.map((t) => [t, 0]));
const samples = {};
const firstMs = {}; // per TOPIC: ms from the subscription to the first decoded message
let subscribedAt = 0;
const readers = new Map(); // channel id -> {topic, key, reader}
const params = {};
let setAnswer = null;
const PARAMS = "@params";

function report(ok, extra) {
  const out = { ok, ...extra, counts, samples, first_ms: firstMs };
  if (PARAMS in counts) Object.assign(out, { params, set_answer: setAnswer });
  console.log(JSON.stringify(out));
}

function fail(why) {
  report(false, { error: why });
  process.exit(1);
}

function done() {
  if (min > 0 && wanted.every((t) => counts[t] >= min)) {
    report(true, {});
    process.exit(0);
  }
}

// the numbers a plot or the 3D view takes from each kind of message
function numbers(schemaName, m) {
  switch (schemaName) {
    case "geometry_msgs/msg/PoseStamped":
      return [m.pose.position.x, m.pose.position.y, m.pose.orientation.z, m.pose.orientation.w,
              m.header.stamp.sec, m.header.stamp.nanosec];
    case "geometry_msgs/msg/Vector3Stamped":
      return [m.vector.x, m.vector.y, m.vector.z, m.header.stamp.sec];
    case "visualization_msgs/msg/MarkerArray":
      if (m.markers.length === 0) return [NaN];
      return m.markers.flatMap((k) => [k.pose.position.x, ...k.points.flatMap((p) => [p.x, p.y])]);
    case "nav_msgs/msg/Path":
      return m.poses.flatMap((p) => [p.pose.position.x, p.pose.position.y]);
    default:
      return [];
  }
}

// foxglove-sdk servers speak the ws-protocol spec under the subprotocol name
// "foxglove.sdk.v1" (the Foxglove app's); this client's own is "foxglove.websocket.v1"
const client = new FoxgloveClient({
  ws: new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
client.on("error", (e) => fail(`websocket: ${e && e.message}`));
client.on("close", () => fail("the server closed the connection"));
client.on("serverInfo", (info) => {
  if (!(PARAMS in counts)) return;
  if (!(info.capabilities || []).includes("parameters")) fail("no parameters capability");
  client.getParameters([], "all");
});
client.on("parameterValues", ({ parameters, id }) => {
  if (id === "all") {
    for (const p of parameters) params[p.name] = p.value;
    const first = parameters.find((p) => typeof p.value === "number");
    if (first === undefined) fail("no numeric parameter to change");
    client.setParameters([{ name: first.name, value: first.value + 1 }], "set");
  } else if (id === "set") {
    setAnswer = Object.fromEntries(parameters.map((p) => [p.name, p.value]));
    counts[PARAMS] = Object.keys(params).length;
    done();
  }
});
client.on("advertise", (channels) => {
  for (const ch of channels) {
    const key = wanted.find((t) => ch.topic.endsWith(t));
    if (key === undefined) continue;
    if (ch.encoding !== "cdr" || ch.schemaEncoding !== "ros2msg") {
      fail(`${ch.topic}: encoding ${ch.encoding}/${ch.schemaEncoding}, expected cdr/ros2msg`);
    }
    const reader = new MessageReader(parse(ch.schema, { ros2: true }));
    readers.set(client.subscribe(ch.id), { topic: ch.topic, key, reader, schema: ch.schemaName });
  }
  subscribedAt = Date.now();
  console.error(`subscribed to ${readers.size} channels`); // a caller may wait for this
});
client.on("message", ({ subscriptionId, data }) => {
  const r = readers.get(subscriptionId);
  if (r === undefined) return;
  let m;
  try {
    m = r.reader.readMessage(data);
  } catch (e) {
    fail(`${r.topic}: does not decode: ${e.message}`);
  }
  const nums = numbers(r.schema, m);
  if (!nums.every((x) => typeof x === "number" && Number.isFinite(x))) {
    fail(`${r.topic}: a field is not a finite number: ${JSON.stringify(m).slice(0, 300)}`);
  }
  counts[r.key] += 1;
  if (!(r.key in firstMs)) firstMs[r.key] = Date.now() - subscribedAt;
  if (!(r.key in samples)) samples[r.key] = { topic: r.topic, schema: r.schema, numbers: nums.slice(0, 6) };
  done();
});
if (min > 0) setTimeout(() => fail("timed out"), 120000);
// stopped from outside (a benchmark's run ended): what was decoded so far
process.on("SIGTERM", () => {
  report(false, { error: "stopped" });
  process.exit(0);
});

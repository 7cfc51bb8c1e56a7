// A Web of Things consumer (node-wot, pinned in package-lock.json) that
// drives an EVATAR Avatar through its exported TD: fetches the TD from the
// node, invokes ACTION with INPUT (JSON) using the operator's bearer token,
// and prints the action's output as one line "OUTPUT <json>"; or reads
// PROPERTY and prints its value the same way.
// Usage: node consume.js TD_URL TOKEN invoke ACTION INPUT_JSON
//        node consume.js TD_URL TOKEN read PROPERTY
"use strict";
const { Servient } = require("@node-wot/core");
const { HttpClientFactory } = require("@node-wot/binding-http");

(async () => {
  const [url, token, op, name, input] = process.argv.slice(2);
  const res = await fetch(url, { headers: { Authorization: "Bearer " + token } });
  if (!res.ok) throw new Error("GET " + url + ": " + res.status);
  const td = await res.json();
  const servient = new Servient();
  servient.addClientFactory(new HttpClientFactory());
  servient.addCredentials({ [td.id]: { token } });
  const WoT = await servient.start();
  const thing = await WoT.consume(td);
  try {
    const out = op === "read" ? await thing.readProperty(name)
                              : await thing.invokeAction(name, JSON.parse(input));
    const value = await out.value();
    console.log("OUTPUT " + JSON.stringify(value));
  } catch (e) {
    console.log("ERROR " + (e && e.message ? e.message : String(e)));
    process.exitCode = 3;
  }
  await servient.shutdown();
})().catch((e) => { console.error(e); process.exit(2); });

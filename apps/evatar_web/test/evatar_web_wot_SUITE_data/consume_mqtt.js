// A node-wot 0.8.16 consumer with only the MQTT binding: it drives a TD's
// MQTT forms (those evatar_web exports for an MQTT Avatar's devices),
// written for evatar_web_wot_SUITE (its packages: evatar_test_npm's
// install_mqtt/0). Usage: node consume_mqtt.js TD_FILE ACTION PROPERTY.
// It observes PROPERTY and, once a value came, prints "OBSERVED <PROPERTY>
// <payload>", invokes ACTION with the payload its MQTT form's
// bil:mqttCommand names ("raw:ON" publishes ON), prints "INVOKED <ACTION>
// <payload>" and exits; "FAILED ..." and status 1 when anything fails.
const fs = require("fs");
const { Servient } = require("@node-wot/core");
const { MqttClientFactory } = require("@node-wot/binding-mqtt");

const [file, action, property] = process.argv.slice(2);
const say = (line) => process.stdout.write(line + "\n");
const fail = (err) => {
  say(`FAILED ${err && err.stack ? err.stack : err}`);
  process.exit(1);
};

const td = JSON.parse(fs.readFileSync(file, "utf8"));
const form = td.actions[action].forms.find((f) => f.href.startsWith("mqtt://"));
const command = form["bil:mqttCommand"];
if (!command || !command.startsWith("raw:")) fail(`no raw bil:mqttCommand on ${action}: ${command}`);
const payload = command.slice("raw:".length);

const servient = new Servient();
servient.addClientFactory(new MqttClientFactory());
servient.start().then(async (WoT) => {
  const thing = await WoT.consume(td);
  let done = false;
  await thing.observeProperty(property, async (output) => {
    if (done) return;
    done = true;
    const text = Buffer.from(await output.arrayBuffer()).toString();
    say(`OBSERVED ${property} ${text}`);
    await thing.invokeAction(action, payload);
    say(`INVOKED ${action} ${payload}`);
    await servient.shutdown();
    process.exit(0);
  }, fail);
}).catch(fail);

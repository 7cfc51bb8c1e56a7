// A node-wot 0.8.16 servient (MQTT binding, against a broker it does not
// host) exposing the lamp of wot_avatar_SUITE's MQTT case, written for the
// test. Usage: node lamp_mqtt.js mqtt://HOST:PORT. node-wot publishes the
// Thing's TD, retained, on the topic "mqtt-lamp". It prints one line per
// fact the suite waits for: "READY <pid>" once the Thing is exposed,
// "TOGGLE mqtt-lamp on <true|false>" for each invocation of its action
// (node-wot's MQTT binding answers nothing to an invocation), "WRITE
// mqtt-lamp brightness <value>" for each write it accepts. A line
// "brightness N" on its standard input sets the brightness from the
// device's side (and so publishes it).
const { Servient } = require("@node-wot/core");
const { MqttBrokerServer } = require("@node-wot/binding-mqtt");

const uri = process.argv[2];
const servient = new Servient();
servient.addServer(new MqttBrokerServer({ uri, clientId: `evatar-suite-lamp-${process.pid}` }));

const say = (line) => process.stdout.write(line + "\n");

servient.start().then(async (WoT) => {
  const state = { brightness: 50, on: false };
  const lamp = await WoT.produce({
    title: "mqtt-lamp",
    properties: {
      brightness: { type: "integer", minimum: 0, maximum: 100, unit: "%", observable: true },
    },
    actions: { toggle: {} },
  });
  lamp.setPropertyReadHandler("brightness", async () => state.brightness);
  lamp.setPropertyWriteHandler("brightness", async (value) => {
    state.brightness = await value.value();
    say(`WRITE mqtt-lamp brightness ${state.brightness}`);
    await lamp.emitPropertyChange("brightness");
  });
  lamp.setActionHandler("toggle", async () => {
    state.on = !state.on;
    say(`TOGGLE mqtt-lamp on ${state.on}`);
    return undefined;
  });
  await lamp.expose();

  let buffer = "";
  process.stdin.on("data", (chunk) => {
    buffer += chunk.toString();
    let i;
    while ((i = buffer.indexOf("\n")) >= 0) {
      const [word, arg] = buffer.slice(0, i).trim().split(" ");
      buffer = buffer.slice(i + 1);
      if (word === "brightness") {
        state.brightness = parseInt(arg, 10);
        lamp.emitPropertyChange("brightness");
      }
    }
  });
  process.stdin.on("end", () => process.exit(0));
  say(`READY ${process.pid}`);
}).catch((err) => {
  say(`FAILED ${err && err.stack ? err.stack : err}`);
  process.exit(1);
});

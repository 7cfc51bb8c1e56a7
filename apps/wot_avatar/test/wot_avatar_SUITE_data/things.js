// A node-wot servient (HTTP binding) exposing the three Things of
// wot_avatar_SUITE: a lamp, a thermostat and a motion sensor, written for the
// test. Usage: node things.js PORT. It prints one line per fact the suite
// waits for: "READY <pid>" once every Thing is exposed, "WRITE <thing>
// <property> <value>" for each write it accepts, "SUBSCRIBED <thing>
// <event>" and "OBSERVED <thing> <property>" when a consumer's long-poll is
// registered (an event emitted before is lost, as node-wot's long-poll
// does). A line "motion" on its standard input emits the sensor's event.
const { Servient } = require("@node-wot/core");
const { HttpServer } = require("@node-wot/binding-http");

const port = parseInt(process.argv[2], 10);
const servient = new Servient();
servient.addServer(new HttpServer({ port, baseUri: `http://127.0.0.1:${port}` }));

const say = (line) => process.stdout.write(line + "\n");

servient.start().then(async (WoT) => {
  const state = { brightness: 50, on: false, setpoint: 21, temperature: 19.5 };

  const lamp = await WoT.produce({
    title: "lamp",
    properties: {
      brightness: { type: "integer", minimum: 0, maximum: 100, unit: "%", observable: true },
    },
    actions: {
      toggle: { output: { type: "object", properties: { on: { type: "boolean" } } } },
    },
  });
  lamp.setPropertyReadHandler("brightness", async () => state.brightness);
  lamp.setPropertyWriteHandler("brightness", async (value) => {
    state.brightness = await value.value();
    say(`WRITE lamp brightness ${state.brightness}`);
    await lamp.emitPropertyChange("brightness");
  });
  lamp.setPropertyObserveHandler("brightness", async () => say("OBSERVED lamp brightness"));
  lamp.setActionHandler("toggle", async () => {
    state.on = !state.on;
    return { on: state.on };
  });

  const thermostat = await WoT.produce({
    title: "thermostat",
    properties: {
      setpoint: { type: "number", minimum: 10, maximum: 30, unit: "degree Celsius" },
      temperature: { type: "number", readOnly: true, unit: "degree Celsius" },
    },
  });
  thermostat.setPropertyReadHandler("setpoint", async () => state.setpoint);
  thermostat.setPropertyWriteHandler("setpoint", async (value) => {
    state.setpoint = await value.value();
    say(`WRITE thermostat setpoint ${state.setpoint}`);
  });
  thermostat.setPropertyReadHandler("temperature", async () => state.temperature);

  const motion = await WoT.produce({
    title: "motion-sensor",
    events: {
      motion: {
        data: { type: "object", properties: { detected: { type: "boolean" }, zone: { type: "string" } } },
      },
    },
  });
  motion.setEventSubscribeHandler("motion", async () => say("SUBSCRIBED motion-sensor motion"));

  await lamp.expose();
  await thermostat.expose();
  await motion.expose();

  let buffer = "";
  process.stdin.on("data", (chunk) => {
    buffer += chunk.toString();
    let i;
    while ((i = buffer.indexOf("\n")) >= 0) {
      const line = buffer.slice(0, i).trim();
      buffer = buffer.slice(i + 1);
      if (line === "motion") motion.emitEvent("motion", { detected: true, zone: "hall" });
    }
  });
  process.stdin.on("end", () => process.exit(0));
  say(`READY ${process.pid}`);
}).catch((err) => {
  say(`FAILED ${err && err.stack ? err.stack : err}`);
  process.exit(1);
});

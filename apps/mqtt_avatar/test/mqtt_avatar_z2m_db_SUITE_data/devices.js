// Prints every device definition of zigbee-herdsman-converters (the
// version package-lock.json pins) as one line of JSON each: an entry of
// zigbee2mqtt's retained bridge/devices list, as zigbee2mqtt publishes it
// for an interviewed device of that definition. Dynamic exposes are
// evaluated as zigbee-herdsman-converters itself does without a device
// (`isDummyDevice`). A definition whose exposes cannot be evaluated so is
// printed as {"error": ...} with its model.
"use strict";
const fs = require("fs");
const path = require("path");
const zhc = require("zigbee-herdsman-converters");

const dir = path.join(path.dirname(require.resolve("zigbee-herdsman-converters")), "devices");
const files = fs.readdirSync(dir).filter((f) => f.endsWith(".js")).sort();
let n = 0;
for (const file of files) {
    const mod = require(path.join(dir, file));
    const defs = mod.definitions || (mod.default && mod.default.definitions) || [];
    for (const raw of defs) {
        n += 1;
        const ieee = "0x" + n.toString(16).padStart(16, "0");
        let line;
        try {
            const def = zhc.prepareDefinition(raw);
            const exposes = typeof def.exposes === "function"
                ? def.exposes({isDummyDevice: true}, {}) : def.exposes;
            line = {
                ieee_address: ieee,
                type: "EndDevice",
                friendly_name: ieee,
                supported: true,
                interview_completed: true,
                definition: {
                    model: def.model,
                    vendor: def.vendor,
                    description: def.description,
                    exposes: exposes,
                    options: def.options || [],
                },
            };
        } catch (e) {
            line = {error: String(e && e.message || e), model: raw.model, vendor: raw.vendor, file: file};
        }
        process.stdout.write(JSON.stringify(line) + "\n");
    }
}

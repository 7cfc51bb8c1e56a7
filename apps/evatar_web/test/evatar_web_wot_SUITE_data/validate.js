// Checks Thing Descriptions with the Thing Description Playground
// (@thing-description-playground/core, pinned in package-lock.json): the
// TD 1.1 JSON Schema (with and without defaults, the "full" schema) and the
// playground's additional assertion checks (security, unique names,
// multi-language consistency, links, URI-variable security). Its JSON-LD
// step fetches the @context online and is switched off.
// Usage: node validate.js FILE.json...   (a file holds one TD or an array)
// Prints one line per TD; exits 1 when any TD fails a check.
"use strict";
const fs = require("fs");
const { tdValidator } = require("@thing-description-playground/core");

async function check(td) {
  const logs = [];
  const r = await tdValidator(JSON.stringify(td), (m) => logs.push(m),
                              { checkDefaults: true, checkJsonLd: false, checkTmConformance: false });
  const failed = [];
  for (const [k, v] of Object.entries(r.report)) {
    if (v === "failed") failed.push(k);
  }
  for (const [k, v] of Object.entries(r.details)) {
    if (v === "failed") failed.push("details." + k);
  }
  return { failed, report: r.report, details: r.details, logs };
}

(async () => {
  let bad = 0, n = 0;
  for (const file of process.argv.slice(2)) {
    const data = JSON.parse(fs.readFileSync(file, "utf8"));
    for (const td of Array.isArray(data) ? data : [data]) {
      n++;
      const { failed, report, details, logs } = await check(td);
      if (report.schema !== "passed") failed.push("schema not passed: " + report.schema);
      if (failed.length) {
        bad++;
        console.log("FAIL " + td.id + " " + JSON.stringify({ failed, report, details }));
        console.log(logs.join("\n"));
      } else {
        console.log("OK " + td.id + " " + JSON.stringify({ report, details }));
      }
    }
  }
  console.log(`checked ${n} TDs, ${bad} failed`);
  process.exit(bad || n === 0 ? 1 : 0);
})().catch((e) => { console.error(e); process.exit(2); });

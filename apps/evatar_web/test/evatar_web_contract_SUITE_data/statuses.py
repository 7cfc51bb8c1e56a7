"""What the contract fuzzer's requests got back, per operation.

Reads schemathesis's NDJSON report (argument 1) and prints, for every
operation of the document, how many requests were sent with its method and
the statuses they got, then the total, then the operations that never got
a 2xx (so were tested against no real data), one line:
  operations without a 2xx: none | LABEL, LABEL, ...
"""
import collections
import json
import sys

statuses = collections.defaultdict(collections.Counter)
for line in open(sys.argv[1], encoding="utf-8"):
    event = json.loads(line)
    scenario = event.get("ScenarioFinished")
    if not scenario:
        continue
    recorder = scenario["recorder"]
    label = recorder["label"]
    method = label.split(" ", 1)[0]
    for case_id, interaction in recorder.get("interactions", {}).items():
        case = recorder.get("cases", {}).get(case_id, {}).get("value", {})
        if case.get("method", "").upper() != method:
            continue  # another method sent to see a 405: not this operation
        response = interaction.get("response")
        statuses[label][response["status_code"] if response else "no answer"] += 1

total = 0
for label in sorted(statuses):
    counts = statuses[label]
    total += sum(counts.values())
    print("%-44s %5d  %s" % (label, sum(counts.values()),
                              " ".join("%s:%d" % kv for kv in sorted(counts.items(), key=str))))
print("%d requests to %d operations" % (total, len(statuses)))
missing = [label for label in sorted(statuses)
           if not any(isinstance(s, int) and 200 <= s < 300 for s in statuses[label])]
print("operations without a 2xx: %s" % (", ".join(missing) or "none"))

"""Parses the Prometheus text exposition format on stdin with the reference
parser (prometheus_client, Debian's python3-prometheus-client) and prints
one line per sample: name TAB its labels sorted, as key=hex(UTF-8 value)
joined by commas, TAB value; and one line per family: `# family TAB NAME TAB
TYPE`. Exits 1 on a parse error."""
import sys

from prometheus_client.parser import text_string_to_metric_families

text = sys.stdin.read()
try:
    for family in text_string_to_metric_families(text):
        print("# family\t%s\t%s" % (family.name, family.type))
        for s in family.samples:
            labels = ",".join("%s=%s" % (k, v.encode("utf-8").hex())
                              for k, v in sorted(s.labels.items()))
            print("%s\t%s\t%r" % (s.name, labels, s.value))
except Exception as e:  # the parser's errors are ValueError and others
    print("parse error: %s" % e, file=sys.stderr)
    sys.exit(1)

"""Checks a live EVATAR node's HTTP API against its OpenAPI document.

Usage: check_openapi.py OPENAPI_JSON BASE_URL PAIRING MQTT_AVATAR  (token in EVATAR_TOKEN)

Validates the document itself (openapi-spec-validator), then sends real
requests to BASE_URL (good and bad ones, with and without the operator
token) and validates every answer - status, content type and body - with
openapi-core against the document. Exits 1 when any answer does not match,
or when an answer's status is not the one the request expects. Then gives
the same check deliberately wrong answers (real ones, altered) and exits 1
when any of them is accepted: the checker is shown able to fail.
"""
import json
import os
import sys
import urllib.error
import urllib.request

from openapi_core import OpenAPI
from openapi_core.testing import MockRequest, MockResponse

spec_path, base, pairing, avatar, thing = (sys.argv[1], sys.argv[2].rstrip("/"), sys.argv[3], sys.argv[4],
                                           sys.argv[5])
token = os.environ["EVATAR_TOKEN"]
api = OpenAPI.from_file_path(spec_path)  # validates the document first

AUTH = {"Authorization": "Bearer " + token}
P = "/api/pairings/" + pairing
CASES = [
    # method, path, path pattern, headers, body, expected status
    ("GET", "/api/cluster", None, {}, None, 200),
    ("GET", "/api/cluster", None, {"Host": "evil.example"}, None, 403),
    ("GET", "/api/cluster", None, {"Authorization": "Bearer wrong"}, None, 401),
    ("GET", "/api/openapi.json", None, {}, None, 200),
    ("GET", "/api/pairings", None, {}, None, 200),
    ("GET", P, "/api/pairings/{id}", {}, None, 200),
    ("GET", P + "/bindings", "/api/pairings/{id}/bindings", {}, None, 200),
    ("GET", "/api/pairings/nope", "/api/pairings/{id}", {}, None, 404),
    ("GET", "/api/pairings/nope/bindings", "/api/pairings/{id}/bindings", {}, None, 404),
    ("POST", "/api/pairings", None, {}, {"id": "oa-tmp"}, 401),
    ("POST", "/api/pairings", None, AUTH, {"id": "oa-tmp", "join_timeout": -1}, 400),
    ("POST", "/api/pairings", None, AUTH,
     {"id": "oa-tmp", "agent_credential": "agent-secret-1", "avatar_credential": "avatar-secret-1",
      "identities": [{"entity": "cam", "role": "avatar", "credential": "cam-secret-1"}]}, 201),
    ("POST", "/api/pairings", None, AUTH,
     {"id": "oa-tmp", "agent_credential": "agent-secret-1", "avatar_credential": "avatar-secret-1"}, 409),
    ("PUT", "/api/pairings/oa-tmp", "/api/pairings/{id}", AUTH, {"feedback_timeout": 2500}, 200),
    ("PUT", "/api/pairings/oa-tmp", "/api/pairings/{id}", AUTH, {"feedback_timeout": "soon"}, 400),
    ("PUT", "/api/pairings/nope", "/api/pairings/{id}", AUTH, {"feedback_timeout": 1}, 404),
    ("POST", "/api/pairings/oa-tmp/rotate", "/api/pairings/{id}/rotate", AUTH, {"entity": "cam"}, 200),
    ("POST", "/api/pairings/oa-tmp/rotate", "/api/pairings/{id}/rotate", AUTH,
     {"role": "agent", "credential": "new-agent-secret"}, 200),
    ("POST", "/api/pairings/oa-tmp/rotate", "/api/pairings/{id}/rotate", AUTH, {"role": "robot"}, 400),
    ("DELETE", "/api/pairings/oa-tmp", "/api/pairings/{id}", AUTH, None, 200),
    ("DELETE", "/api/pairings/oa-tmp", "/api/pairings/{id}", AUTH, None, 404),
    ("DELETE", P, "/api/pairings/{id}", {}, None, 401),
    ("GET", "/api/mqtt_avatars", None, {}, None, 200),
    ("GET", "/api/mqtt_avatars/" + avatar, "/api/mqtt_avatars/{id}", {}, None, 200),
    ("GET", "/api/mqtt_avatars/" + avatar + "/problems", "/api/mqtt_avatars/{id}/problems", {}, None, 200),
    ("PUT", "/api/mqtt_avatars/" + avatar + "/description", "/api/mqtt_avatars/{id}/description", AUTH,
     {"overrides": {"any device": {"room": "hall"}}}, 200),
    ("PUT", "/api/mqtt_avatars/" + avatar + "/description", "/api/mqtt_avatars/{id}/description", AUTH,
     {"xml": "<not-bil/>"}, 400),
    ("GET", "/api/mqtt_avatars/nope", "/api/mqtt_avatars/{id}", {}, None, 404),
    ("GET", "/api/mqtt_avatars/nope/problems", "/api/mqtt_avatars/{id}/problems", {}, None, 404),
    ("PUT", "/api/mqtt_avatars/nope/description", "/api/mqtt_avatars/{id}/description", AUTH,
     {"xml": "<x/>"}, 404),
    ("PUT", "/api/mqtt_avatars/nope/description", "/api/mqtt_avatars/{id}/description", AUTH,
     {"colour": 1}, 400),
    ("GET", "/api/wot_avatars", None, {}, None, 200),
    ("GET", "/api/wot_avatars/" + thing + "/problems", "/api/wot_avatars/{id}/problems", {}, None, 200),
    ("GET", "/api/wot_avatars/nope/problems", "/api/wot_avatars/{id}/problems", {}, None, 404),
    ("PATCH", "/api/cluster", None, AUTH, None, 405),
]


def check(method, path, pattern, headers, data, status, ctype, raw, answer_headers=None):
    """The problem with one answer under the document, or None."""
    request = MockRequest("http://localhost", method.lower(), path, path_pattern=pattern or path,
                          headers=headers, data=data,
                          content_type="application/json" if data is not None else None)
    response = MockResponse(raw, status_code=status, content_type=(ctype or "").split(";")[0],
                            headers=answer_headers or {})
    try:
        api.validate_response(request, response)
    except Exception as e:  # every validation error: report it, go on
        problem = "%s: %s" % (type(e).__name__, e)
        cause = getattr(e, "__cause__", None)
        if cause is not None:
            problem += " (%s)" % "; ".join(str(x) for x in getattr(cause, "schema_errors", [cause]))
        return problem
    if ctype is None or not ctype.startswith("application/json"):
        return "content type %r is not JSON" % ctype
    return None


failures = 0
answers = {}
for method, path, pattern, headers, body, expected in CASES:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method, headers=dict(headers))
    if data is not None:
        req.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            status, ctype, raw = r.status, r.headers.get("Content-Type"), r.read()
            answer_headers = dict(r.headers.items())
    except urllib.error.HTTPError as e:
        status, ctype, raw = e.code, e.headers.get("Content-Type"), e.read()
        answer_headers = dict(e.headers.items())
    answers.setdefault((method, path, status), (pattern, headers, data, ctype, raw))
    problem = None
    if status != expected:
        problem = "status %d, expected %d: %s" % (status, expected, raw[:300])
    elif status == 405:
        pass  # not an operation of the document: checked for its JSON error only
    else:
        problem = check(method, path, pattern, headers, data, status, ctype, raw, answer_headers)
    if ctype is None or not ctype.startswith("application/json"):
        problem = problem or "content type %r is not JSON" % ctype
    print("%-6s %-45s %d %s" % (method, path, status, "ok" if problem is None else "FAIL " + problem))
    failures += problem is not None

print("%d answers checked against %s, %d not matching" % (len(CASES), spec_path, failures))


# The checker itself must be able to fail: real answers made wrong on
# purpose go through the same check() and each must be refused.
def wrong(key, mutate, ctype=None):
    pattern, headers, data, real_ctype, raw = answers[key]
    body = json.loads(raw)
    return key, pattern, headers, data, ctype or real_ctype, json.dumps(mutate(body)).encode()


def bad_reason(b):
    b["unbound"][0]["reason"] = "Bogus"
    return b


def drop(name):
    def f(b):
        del b[name]
        return b
    return f


WRONG = [
    wrong(("GET", P + "/bindings", 200), bad_reason),                 # not in the enum
    wrong(("GET", P + "/bindings", 200), lambda b: dict(b, extra=1)),  # unknown property
    wrong(("GET", "/api/pairings/nope", 404), drop("error")),         # required field missing
    wrong(("GET", "/api/cluster", 200), lambda b: [b]),               # wrong type
    wrong(("GET", "/api/cluster", 200), lambda b: b, "text/html"),    # wrong content type
]
accepted = 0
for (method, path, status), pattern, headers, data, ctype, raw in WRONG:
    problem = check(method, path, pattern, headers, data, status, ctype, raw)
    print("wrong  %-6s %-38s %d %s" % (method, path, status,
                                       "ACCEPTED (the checker cannot fail)" if problem is None
                                       else "refused: " + problem[:200]))
    accepted += problem is None
print("%d wrong answers given to the checker, %d accepted" % (len(WRONG), accepted))
sys.exit(1 if failures or accepted else 0)

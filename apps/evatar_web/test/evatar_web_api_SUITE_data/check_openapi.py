"""Checks a live EVATAR node's HTTP API against its OpenAPI document.

Usage: check_openapi.py OPENAPI_JSON BASE_URL PAIRING MQTT_AVATAR  (token in EVATAR_TOKEN)

Validates the document itself (openapi-spec-validator), then sends real
requests to BASE_URL (good and bad ones, with and without the operator
token) and validates every answer - status, content type and body - with
openapi-core against the document. Exits 1 when any answer does not match,
or when an answer's status is not the one the request expects.
"""
import json
import os
import sys
import urllib.error
import urllib.request

from openapi_core import OpenAPI
from openapi_core.testing import MockRequest, MockResponse

spec_path, base, pairing, avatar = sys.argv[1], sys.argv[2].rstrip("/"), sys.argv[3], sys.argv[4]
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
    ("PATCH", "/api/cluster", None, AUTH, None, 405),
]

failures = 0
for method, path, pattern, headers, body, expected in CASES:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method, headers=dict(headers))
    if data is not None:
        req.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            status, ctype, raw = r.status, r.headers.get("Content-Type"), r.read()
    except urllib.error.HTTPError as e:
        status, ctype, raw = e.code, e.headers.get("Content-Type"), e.read()
    problem = None
    if status != expected:
        problem = "status %d, expected %d: %s" % (status, expected, raw[:300])
    elif status == 405:
        pass  # not an operation of the document: checked for its JSON error only
    else:
        request = MockRequest("http://localhost", method.lower(), path, path_pattern=pattern or path,
                              headers=headers, data=data,
                              content_type="application/json" if data is not None else None)
        response = MockResponse(raw, status_code=status, content_type=ctype.split(";")[0])
        try:
            api.validate_response(request, response)
        except Exception as e:  # every validation error: report it, go on
            problem = "%s: %s" % (type(e).__name__, e)
            cause = getattr(e, "__cause__", None)
            if cause is not None:
                problem += " (%s)" % "; ".join(str(x) for x in getattr(cause, "schema_errors", [cause]))
    if ctype is None or not ctype.startswith("application/json"):
        problem = problem or "content type %r is not JSON" % ctype
    print("%-6s %-45s %d %s" % (method, path, status, "ok" if problem is None else "FAIL " + problem))
    failures += problem is not None

print("%d answers checked against %s, %d not matching" % (len(CASES), spec_path, failures))
sys.exit(1 if failures else 0)

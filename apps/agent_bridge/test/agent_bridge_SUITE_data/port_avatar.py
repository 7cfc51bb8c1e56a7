#!/usr/bin/env python3
"""A tiny Avatar for agent_bridge_SUITE: speaks EVATAR frames on stdin/stdout
(4-byte big-endian length + one BIL document), answers the first request
with a Feedback, says so on stderr, then exits so the connector restarts it.
Usage: port_avatar.py PAIRING CREDENTIAL"""
import re
import struct
import sys
from xml.sax.saxutils import escape

NS = 'xmlns:bil="urn:evatar:bil:1"'


def send(doc):
    data = doc.encode("utf-8")
    sys.stdout.buffer.write(struct.pack(">I", len(data)) + data)
    sys.stdout.buffer.flush()


def recv():
    head = sys.stdin.buffer.read(4)
    if len(head) < 4:
        sys.exit(0)
    (size,) = struct.unpack(">I", head)
    return sys.stdin.buffer.read(size).decode("utf-8")


def field(doc, name):
    m = re.search("<%s>([^<]*)</%s>" % (name, name), doc)
    return m.group(1) if m else ""


pairing, credential = sys.argv[1], sys.argv[2]
send('<bil:Hello %s><Pairing>%s</Pairing><Role>avatar</Role><EntityID>port-av</EntityID>'
     '<Credential>%s</Credential><ProtocolVersion>1</ProtocolVersion></bil:Hello>'
     % (NS, escape(pairing), escape(credential)))
reply = recv()
if "Welcome" not in reply:
    sys.stderr.write("port_avatar: refused: %s\n" % field(reply, "Code"))
    sys.exit(2)
send('<bil:description %s><bil:context><EntityID>port-av</EntityID><APIName>PORT</APIName>'
     '<EntityType>Avatar</EntityType><Context>ActuatorDescription</Context></bil:context>'
     '<bil:types><bil:Component><ComponentID>Light01</ComponentID><Service>'
     '<ServiceCategory>ACTUATOR</ServiceCategory><ServiceType>TurnLightOn</ServiceType>'
     '</Service></bil:Component></bil:types></bil:description>' % NS)
while True:
    doc = recv()
    if "<Context>RequestAwaitingFeedback</Context>" in doc:
        sid = field(doc, "SignalID")
        send('<bil:Envelope %s><bil:Header><SignalID>port-%s</SignalID><Context>Feedback</Context>'
             '<Sender>%s</Sender><Receiver>%s</Receiver><InReplyTo>%s</InReplyTo>'
             '<Timestamp>0</Timestamp></bil:Header><bil:Body><ServiceCategory>ACTUATOR'
             '</ServiceCategory><ServiceType>TurnLightOn</ServiceType></bil:Body></bil:Envelope>'
             % (NS, sid, field(doc, "Receiver"), field(doc, "Sender"), sid))
        sys.stderr.write("port_avatar: answered %s\n" % sid)
        sys.stderr.flush()
        sys.exit(0)

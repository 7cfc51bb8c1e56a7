"""A small XML parser for BIL's subset of XML (docs/bil.md, section 1).

It is written by hand, with no dependency, so that it can refuse what a
general parser would accept: any ``<!DOCTYPE`` (so any entity declaration)
gives ``doctype_refused``, any reference ``&name;`` other than the five
predefined entities gives ``entity_refused``. Nothing in a document can make
it grow. Element names are resolved against their namespace declarations;
attributes other than namespace declarations are ignored, as BIL says.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

__all__ = ["BilError", "Element", "parse", "escape_text"]

MAX_DEPTH = 32

_NAME_START = "A-Za-z_\u00c0-\u00d6\u00d8-\u00f6\u00f8-\u02ff\u0370-\u037d\u037f-\u1fff\u200c-\u200d\u2070-\u218f\u2c00-\u2fef\u3001-\ud7ff\uf900-\ufdcf\ufdf0-\ufffd\U00010000-\U000effff"
_NAME_CHAR = _NAME_START + r"\-.0-9\u00b7\u0300-\u036f\u203f-\u2040"
_QNAME = re.compile("[%s][%s]*(?::[%s][%s]*)?" % (_NAME_START, _NAME_CHAR, _NAME_START, _NAME_CHAR))
_NCNAME = re.compile("[%s][%s]*\\Z" % (_NAME_START, _NAME_CHAR))
_WS = re.compile(r"[ \t\r\n]*")
_TEXT = re.compile(r"[^<&]*")
_FORBIDDEN = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff\ud800-\udfff]")
_DECL = re.compile(r"<\?xml[ \t\r\n]+version[ \t\r\n]*=[ \t\r\n]*(['\"])1\.[0-9]+\1"
                   r"(?:[ \t\r\n]+encoding[ \t\r\n]*=[ \t\r\n]*(['\"])([A-Za-z][A-Za-z0-9._\-]*)\2)?"
                   r"(?:[ \t\r\n]+standalone[ \t\r\n]*=[ \t\r\n]*(['\"])(?:yes|no)\4)?"
                   r"[ \t\r\n]*\?>")
_PREDEFINED = {"lt": "<", "gt": ">", "amp": "&", "quot": '"', "apos": "'"}
_XML_NS = "http://www.w3.org/XML/1998/namespace"


class BilError(Exception):
    """A document was refused. ``code`` is one of the codes of docs/bil.md
    section 5 (``malformed``, ``doctype_refused``, ``entity_refused``,
    ``too_large``, ``truncated``, ``bad_encoding``, ``too_deep``,
    ``wrong_root``, ``missing_element``, ...); ``message`` says why."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__("%s: %s" % (code, message))
        self.code = code
        self.message = message


@dataclass
class Element:
    """An element: its namespace (``""`` for none), local name and children,
    text nodes being ``str`` (adjacent text, references and CDATA are
    merged; whitespace-only text is dropped beside child elements)."""

    ns: str
    name: str
    children: List[Union["Element", str]] = field(default_factory=list)

    def elements(self) -> List["Element"]:
        return [c for c in self.children if isinstance(c, Element)]

    def text(self) -> Optional[str]:
        """The text of a leaf element ('' when empty), None if it holds elements."""
        if any(isinstance(c, Element) for c in self.children):
            return None
        return "".join(c for c in self.children if isinstance(c, str))


def escape_text(text: str) -> str:
    """Escapes text for an element's content, as the Erlang encoder does."""
    return (text.replace("&", "&amp;").replace("<", "&lt;")
            .replace(">", "&gt;").replace("\r", "&#13;"))


def parse(data: bytes, max_size: int = 1048576, max_depth: int = MAX_DEPTH) -> Element:
    """Parses a whole document; raises BilError."""
    if not isinstance(data, (bytes, bytearray)):
        raise BilError("not_binary", "a document must be bytes")
    if len(data) > max_size:
        raise BilError("too_large", "document of %d bytes is over the limit of %d"
                       % (len(data), max_size))
    raw = bytes(data)
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        text = raw.decode("utf-8", errors="strict")
    except UnicodeDecodeError as e:
        raise BilError("bad_encoding", "not UTF-8 at byte %d" % e.start) from None
    bad = _FORBIDDEN.search(text)
    if bad:
        raise BilError("bad_encoding", "character U+%04X is not allowed in XML at %d"
                       % (ord(bad.group()), bad.start()))
    return _Parser(text, max_depth).document()


class _Parser:
    def __init__(self, text: str, max_depth: int) -> None:
        self.s = text
        self.i = 0
        self.max_depth = max_depth

    def fail(self, code: str, message: str) -> BilError:
        line = self.s.count("\n", 0, self.i) + 1
        col = self.i - (self.s.rfind("\n", 0, self.i) + 1) + 1
        return BilError(code, "%s (line %d, column %d)" % (message, line, col))

    def ws(self) -> None:
        m = _WS.match(self.s, self.i)
        assert m is not None
        self.i = m.end()

    def document(self) -> Element:
        s = self.s
        if s.startswith("<?xml", 0) and (len(s) > 5 and s[5] in " \t\r\n?"):
            m = _DECL.match(s, 0)
            if not m:
                if "?>" not in s:
                    raise self.fail("truncated", "the XML declaration is not closed")
                raise self.fail("malformed", "bad XML declaration")
            enc = m.group(3)
            if enc is not None and enc.lower() not in ("utf-8", "utf8"):
                raise self.fail("bad_encoding", "declared encoding %s is not UTF-8" % enc)
            self.i = m.end()
        self.misc()
        if self.i >= len(s):
            raise self.fail("truncated", "no root element")
        if s.startswith("<!DOCTYPE", self.i):
            raise self.fail("doctype_refused", "a DOCTYPE is refused (it could declare entities)")
        if s[self.i] != "<":
            raise self.fail("malformed", "text before the root element")
        root = self.element({"xml": _XML_NS}, 1)
        self.misc()
        if self.i < len(s):
            if s.startswith("<!DOCTYPE", self.i):
                raise self.fail("doctype_refused", "a DOCTYPE is refused")
            raise self.fail("malformed", "content after the root element")
        return root

    def misc(self) -> None:
        """Whitespace, comments and processing instructions."""
        while True:
            self.ws()
            if self.s.startswith("<!--", self.i):
                self.comment()
            elif self.s.startswith("<?", self.i):
                self.pi()
            else:
                return

    def comment(self) -> None:
        end = self.s.find("-->", self.i + 4)
        if end < 0:
            raise self.fail("truncated", "comment not closed")
        if "--" in self.s[self.i + 4:end]:
            raise self.fail("malformed", "'--' inside a comment")
        self.i = end + 3

    def pi(self) -> None:
        m = _QNAME.match(self.s, self.i + 2)
        if not m:
            raise self.fail("malformed", "bad processing instruction")
        if m.group().lower() == "xml":
            raise self.fail("malformed", "XML declaration not at the start")
        end = self.s.find("?>", m.end())
        if end < 0:
            raise self.fail("truncated", "processing instruction not closed")
        self.i = end + 2

    def element(self, scope: Dict[str, str], depth: int) -> Element:
        if depth > self.max_depth:
            raise self.fail("too_deep", "elements nested deeper than %d" % self.max_depth)
        s = self.s
        self.i += 1
        m = _QNAME.match(s, self.i)
        if not m:
            if self.i >= len(s):
                raise self.fail("truncated", "the input ends inside a tag")
            raise self.fail("malformed", "bad element name")
        qname = m.group()
        self.i = m.end()
        attrs: List[Tuple[str, str]] = []
        while True:
            had_ws = self.i
            self.ws()
            if self.i >= len(s):
                raise self.fail("truncated", "the input ends inside the tag of %s" % qname)
            c = s[self.i]
            if c == ">" or s.startswith("/>", self.i):
                break
            if had_ws == self.i:
                raise self.fail("malformed", "expected whitespace in the tag of %s" % qname)
            am = _QNAME.match(s, self.i)
            if not am:
                raise self.fail("malformed", "bad attribute in the tag of %s" % qname)
            self.i = am.end()
            self.ws()
            if not s.startswith("=", self.i):
                raise self.fail("truncated" if self.i >= len(s) else "malformed",
                                "expected = after attribute %s" % am.group())
            self.i += 1
            self.ws()
            if self.i >= len(s):
                raise self.fail("truncated", "the input ends inside an attribute")
            q = s[self.i]
            if q not in "'\"":
                raise self.fail("malformed", "attribute value not quoted")
            end = s.find(q, self.i + 1)
            if end < 0:
                raise self.fail("truncated", "attribute value not closed")
            value = self.references(s[self.i + 1:end], attr=True)
            self.i = end + 1
            if any(a[0] == am.group() for a in attrs):
                raise self.fail("malformed", "attribute %s given twice" % am.group())
            attrs.append((am.group(), value))
        new_scope = scope
        for name, value in attrs:
            if name == "xmlns":
                new_scope = dict(new_scope) if new_scope is scope else new_scope
                new_scope[""] = value
            elif name.startswith("xmlns:"):
                if value == "":
                    raise self.fail("malformed", "empty namespace for prefix %s" % name[6:])
                new_scope = dict(new_scope) if new_scope is scope else new_scope
                new_scope[name[6:]] = value
        for name, _ in attrs:
            if ":" in name and not name.startswith("xmlns:") and name.split(":", 1)[0] not in new_scope:
                raise self.fail("malformed", "unbound prefix in attribute %s" % name)
        ns, local = self.resolve(qname, new_scope)
        el = Element(ns, local)
        if s.startswith("/>", self.i):
            self.i += 2
            return el
        self.i += 1
        texts: List[str] = []
        has_el = False
        while True:
            m = _TEXT.match(s, self.i)
            assert m is not None
            if m.end() > self.i:
                chunk = m.group()
                if "]]>" in chunk:
                    self.i += chunk.index("]]>")
                    raise self.fail("malformed", "']]>' in text")
                texts.append(chunk)
                self.i = m.end()
            if self.i >= len(s):
                raise self.fail("truncated", "the input ends inside element %s" % qname)
            if s[self.i] == "&":
                end = s.find(";", self.i)
                if end < 0 or end - self.i > 40:
                    raise self.fail("truncated" if end < 0 else "malformed", "bad reference")
                texts.append(self.reference(s[self.i + 1:end]))
                self.i = end + 1
            elif s.startswith("</", self.i):
                self.i += 2
                em = _QNAME.match(s, self.i)
                if not em:
                    raise self.fail("truncated" if self.i >= len(s) else "malformed", "bad end tag")
                if em.group() != qname:
                    raise self.fail("malformed", "end tag %s does not match %s" % (em.group(), qname))
                self.i = em.end()
                self.ws()
                if self.i >= len(s):
                    raise self.fail("truncated", "the input ends inside an end tag")
                if s[self.i] != ">":
                    raise self.fail("malformed", "bad end tag %s" % qname)
                self.i += 1
                break
            elif s.startswith("<!--", self.i):
                self.flush(el, texts)
                self.comment()
            elif s.startswith("<![CDATA[", self.i):
                end = s.find("]]>", self.i + 9)
                if end < 0:
                    raise self.fail("truncated", "CDATA section not closed")
                texts.append(s[self.i + 9:end])
                self.i = end + 3
            elif s.startswith("<!DOCTYPE", self.i):
                raise self.fail("doctype_refused", "a DOCTYPE is refused")
            elif s.startswith("<?", self.i):
                self.flush(el, texts)
                self.pi()
            elif s.startswith("<!", self.i):
                raise self.fail("malformed", "declaration not allowed here")
            else:
                self.flush(el, texts)
                el.children.append(self.element(new_scope, depth + 1))
                has_el = True
        self.flush(el, texts)
        if has_el:
            el.children = [c for c in el.children
                           if not (isinstance(c, str) and c.strip(" \t\r\n") == "")]
        return el

    @staticmethod
    def flush(el: Element, texts: List[str]) -> None:
        if texts:
            t = "".join(texts)
            texts.clear()
            if el.children and isinstance(el.children[-1], str):
                el.children[-1] += t
            else:
                el.children.append(t)

    def resolve(self, qname: str, scope: Dict[str, str]) -> Tuple[str, str]:
        if ":" in qname:
            prefix, local = qname.split(":", 1)
            if prefix not in scope:
                raise self.fail("malformed", "unbound namespace prefix %s" % prefix)
            return scope[prefix], local
        return scope.get("", ""), qname

    def references(self, raw: str, attr: bool) -> str:
        if "<" in raw:
            raise self.fail("malformed", "'<' in an attribute value")
        out = []
        j = 0
        while True:
            k = raw.find("&", j)
            if k < 0:
                out.append(raw[j:])
                break
            out.append(raw[j:k])
            end = raw.find(";", k)
            if end < 0:
                raise self.fail("malformed", "bad reference in an attribute value")
            out.append(self.reference(raw[k + 1:end]))
            j = end + 1
        return "".join(out)

    def reference(self, name: str) -> str:
        if name.startswith("#"):
            try:
                if name.startswith("#x"):
                    if not re.fullmatch(r"[0-9a-fA-F]+", name[2:]):
                        raise ValueError
                    cp = int(name[2:], 16)
                else:
                    if not re.fullmatch(r"[0-9]+", name[1:]):
                        raise ValueError
                    cp = int(name[1:])
            except ValueError:
                raise self.fail("malformed", "bad character reference &%s;" % name) from None
            if cp > 0x10FFFF or _FORBIDDEN.match(chr(cp)) or cp == 0:
                raise self.fail("bad_encoding", "character reference to a forbidden character")
            return chr(cp)
        if name in _PREDEFINED:
            return _PREDEFINED[name]
        if _NCNAME.match(name):
            raise self.fail("entity_refused", "reference to entity &%s; refused" % name)
        raise self.fail("malformed", "bad reference")


def valid_name(name: str) -> bool:
    """True if ``name`` can be a parameter element name (an NCName)."""
    return bool(_NCNAME.match(name))

"""The session key of a lease, agreed and never sent: X25519 between a client and a node.

A client puts a fresh X25519 public key (``pub``) in each reset request; a node that grants it
a lease answers with a fresh public key of its own. Both derive the same 32-byte session key
from the shared secret, the two public keys and the client id (keyed BLAKE2b over them, the
shared secret as the key). The key itself never travels, so a participant that captures a
reset request, or a reply, or replays either, learns nothing it could sign with: deriving the
key takes the private half of one of the two key pairs, which never leave their process.

Every request of the holder after that is signed (``request_proof``): a MAC under the key of a
label and the request's exact bytes, which carry a request number that only ever grows. The
node accepts each number once (``bridge.net.lease``). Its reply names the request it answers
(``reply_proof``: the request's SHA-256 and the checksum of the active start state, under the
key), so a client knows its own request, unaltered, is what the node served. The whole protocol
is written down in docs/protocol.md.
"""

from __future__ import annotations

import hashlib

from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

from bridge.errors import TransportError
from bridge.net import protocol as proto

PUBLIC_SIZE = 32
_PERSON = b"fmu-bridge-key1"  # BLAKE2b personalisation (at most 16 bytes): version 1 of the derivation


class KeyPair:
    """One side's fresh X25519 key pair for one key agreement (never reused)."""

    def __init__(self) -> None:
        self._private = X25519PrivateKey.generate()
        self.public = self._private.public_key().public_bytes(Encoding.Raw, PublicFormat.Raw)

    def session_key(self, peer: bytes, *, client_pub: bytes, node_pub: bytes, client: int) -> bytes:
        """The session key agreed with the holder of ``peer``; TransportError if ``peer`` is not
        a usable X25519 public key (wrong size, or a low-order point that gives no secret)."""
        if len(peer) != PUBLIC_SIZE:
            raise TransportError(f"a key-agreement public key of {len(peer)} bytes, expected {PUBLIC_SIZE}")
        try:
            shared = self._private.exchange(X25519PublicKey.from_public_bytes(peer))
        except ValueError as exc:
            raise TransportError(f"the key-agreement public key is not usable ({exc})") from None
        label = b"session" + client_pub + node_pub + client.to_bytes(8, "little")
        return hashlib.blake2b(label, key=shared, digest_size=proto.KEY_SIZE, person=_PERSON).digest()


def request_proof(key: bytes, what: str, payload: bytes) -> bytes:
    """The MAC a holder attaches to a request (``what``: ``reset`` or ``state``) of ``payload``."""
    return proto.mac(key, what.encode() + b"\0" + payload)


def reply_proof(key: bytes, request: bytes, state: str) -> bytes:
    """The MAC a node attaches to its answer to ``request`` (the exact request bytes), with the
    checksum ``state`` of the state its episodes start from ("" for none sent)."""
    return proto.mac(key, b"reply\0" + hashlib.sha256(request).digest() + state.encode())

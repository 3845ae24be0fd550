"""How a task opens an application's link end from the spec handed down: one opener per transport and kind."""

from __future__ import annotations

import numpy as np
import pytest

from pbo_runtime import ModuleError
from pbo_runtime.config.application import ENDS
from pbo_runtime.links.ends import OPENERS, open_link_end
from pbo_runtime.links.message_link import MessageLink
from pbo_runtime.links.run_link import RunLink
from pbo_runtime.links.spec import TRANSPORTS
from pbo_runtime.links.triple_buffer import LinkLayout, TripleBuffer
from tests.support import unique_name

pytestmark = pytest.mark.usefixtures("no_leftover_ipc")

LIKE = np.zeros(3)


def spec(kind: str = "periodic", transport: str = "shm", shm_name: str = "") -> RunLink:
    return RunLink(kind, transport, "float64", (3,), shm_name=shm_name)


def test_every_transport_a_file_may_name_has_an_opener_for_every_kind_of_link():
    assert tuple(OPENERS) == TRANSPORTS
    assert all(set(kinds) == set(ENDS) for kinds in OPENERS.values())


def test_an_unknown_transport_is_refused_naming_the_transports():
    with pytest.raises(ModuleError, match=r"^link 'l': unknown transport 'udp' \(transports: shm, zenoh\)$"):
        open_link_end("l", spec(transport="udp"), LIKE, "sender")


def test_a_port_of_another_payload_is_refused_naming_both():
    with pytest.raises(ModuleError, match=r"^link 'l' carries float64 \[3\], but the port is int32 \[2\]: "):
        open_link_end("l", spec(), np.zeros(2, dtype=np.int32), "sender")


def test_a_message_link_has_no_reader():
    with pytest.raises(ModuleError, match=r"^link 'l' carries messages: its ends are 'sender' and 'server', not 'reader'$"):
        open_link_end("l", spec(kind="message"), LIKE, "reader")


def test_a_periodic_shm_end_attaches_to_the_runners_triple_buffer():
    name = unique_name("link")
    with (TripleBuffer.create(name, LinkLayout(LIKE.dtype, LIKE.shape), "sender") as sender,
          open_link_end("l", spec(shm_name=name), LIKE, "reader") as reader):
        assert isinstance(reader, TripleBuffer) and reader.role == "reader"
        sender.write(np.arange(3.0))
        reader.read()
        assert list(reader.value) == [0.0, 1.0, 2.0]


def test_a_message_shm_end_attaches_to_the_runners_queue():
    name = unique_name("msg")
    with MessageLink.create(name, 2):
        end = open_link_end("l", spec(kind="message", shm_name=name), LIKE, "sender")
        try:
            assert isinstance(end, MessageLink) and not end.owner
        finally:
            end.close()

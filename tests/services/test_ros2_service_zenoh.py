"""A ROS 2 service of Ros2Node over real Zenoh on loopback, called as rmw_zenoh's client calls it
(target ALL_COMPLETE, consolidation NONE): ``ros2 service call`` gets its reply."""

from __future__ import annotations

from locnerf.ros2.attachment import Attachment
from locnerf.ros2.naming import data_key
from locnerf.ros2.types import EMPTY_SERVICE, message_class, serialize
from locnerf_services.ros2.node import Ros2Node
from locnerf_services.transport import TransportConfig, open_bus
from tests.ros2.rmw_client import RmwServiceClient
from tests.services.helpers import free_port, wait_until


def test_a_service_answers_an_all_complete_query_with_the_request_sequence_and_gid():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    hub = open_bus(TransportConfig(listen=(endpoint,)))
    server = open_bus(TransportConfig(connect=(endpoint,)))
    client = RmwServiceClient(TransportConfig(connect=(endpoint,)))
    node = Ros2Node(server, 0, "locnerf", "/robot1")
    try:
        response = serialize(message_class(f"{EMPTY_SERVICE}_Response")(), f"{EMPTY_SERVICE}_Response")
        asked: list[Attachment | None] = []
        node.service("reinitialize_global_localization", EMPTY_SERVICE, lambda _key, _payload, request: asked.append(request) or response)
        key = data_key(0, "/robot1/reinitialize_global_localization", EMPTY_SERVICE)
        request = serialize(message_class(f"{EMPTY_SERVICE}_Request")(), f"{EMPTY_SERVICE}_Request")
        sent = Attachment(3, 1, bytes(range(16)))
        replies: list = []
        wait_until(lambda: replies.extend(client.call(key, request, sent.encode(), timeout=1.0)) or bool(replies), 20.0, "a reply to an ALL_COMPLETE query")
        (reply_key, payload, attachment), *others = replies
        answer = Attachment.decode(attachment)
        assert others == [] and (reply_key, payload) == (key, response)
        assert (answer.sequence_number, answer.gid) == (3, sent.gid) and asked[-1] == sent
    finally:
        node.close()
        client.close()
        server.close()
        hub.close()

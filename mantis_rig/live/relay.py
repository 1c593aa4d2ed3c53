"""`--live [HOST:]PORT`: a live view of the stack in Foxglove, from the pip install.

A Foxglove WebSocket server (foxglove-sdk; 127.0.0.1 unless a host is given) relays the
trial's topics as they are published, as foxglove_bridge would on a ROS install: each message's
CDR bytes exactly as received (raw subscriptions: nothing is deserialised or re-serialised),
on a channel with encoding ``cdr`` and the type's full ``ros2msg`` definition as its schema.
The server keeps a bounded queue per client and drops the oldest data for a client that does
not keep up, so a slow viewer never slows the rig. A Foxglove layout for a trial ships in
``config/foxglove/trial_layout.json``.
"""
from __future__ import annotations

from mantis_rig.recording.message_types import message_class
from mantis_rig.runtime.executors import Spinner, light_executor
from mantis_sim.errors import InputError

from ..contract import LIVE_RELAY_NODE, resolve
from ..nodes.recorder import TRIAL_TOPICS, subscription_qos
from ..recording.message_definition import SCHEMA_ENCODING, full_message_definition

DEFAULT_HOST = '127.0.0.1'
BACKLOG_MESSAGES = 1024          # per client; the oldest is dropped beyond it


class LiveError(InputError):
    """The live view cannot start as asked (a bad address, a port in use)."""


def parse_address(text: str) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` (port 0: any free one)."""
    host, sep, port_text = text.rpartition(':')
    host = host if sep else DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        raise LiveError(f'--live {text!r}: expected [HOST:]PORT, e.g. 8765 or '
                        f'127.0.0.1:8765') from None
    if not 0 <= port <= 65535 or not host:
        raise LiveError(f'--live {text!r}: expected [HOST:]PORT with a port of 0-65535')
    return host, port


class LiveRelay:
    """The server and a node whose raw subscriptions feed it, spun by a SingleThreadedExecutor
    in a thread of its own. Start it before the trial: a bad address is refused then."""

    def __init__(self, address: str, ros_context=None, topics=TRIAL_TOPICS, name='mantis_rig',
                 namespace: str = '/'):
        """topics: contract Topics, relayed from the rig in ``namespace``; each channel is
        named by the topic's full name there."""
        import foxglove

        from mantis_rig.runtime.lean_node import LeanNode

        host, port = parse_address(address)
        self._foxglove = foxglove.Context()
        # Every channel exists before the server does, so a client that connects at once is
        # told of all of them together. A channel added while a client was connected was
        # advertised to it before the server had it on record for that client: a subscription
        # that came straight back was refused ("attempted to subscribe to unknown channel"),
        # and that client never got the topic (foxglove-sdk 0.30).
        self.channels = {}
        full_names = {spec.name: resolve(spec.name, namespace) for spec in topics}
        for spec in topics:
            schema = foxglove.Schema(name=spec.type_name, encoding=SCHEMA_ENCODING,
                                     data=full_message_definition(spec.type_name).encode())
            self.channels[full_names[spec.name]] = foxglove.Channel(
                full_names[spec.name], schema=schema, message_encoding='cdr',
                context=self._foxglove)
        try:
            self.server = foxglove.start_server(
                name=name, host=host, port=port, context=self._foxglove,
                supported_encodings=['cdr'], message_backlog_size=BACKLOG_MESSAGES)
        except RuntimeError as exc:
            raise LiveError(f'--live {address}: cannot serve on {host}:{port}: '
                            f'{str(exc).removeprefix("FoxgloveError: ")}') from None
        self.host, self.port = host, self.server.port
        self.node = LeanNode(LIVE_RELAY_NODE, namespace=namespace, context=ros_context,
                             start_parameter_services=False)
        self.relayed = dict.fromkeys(full_names.values(), 0)  # messages passed on, per topic
        for spec in topics:
            full = full_names[spec.name]
            self.node.create_subscription(message_class(spec.type_name), spec.name,
                                          self._relay(full, self.channels[full]),
                                          subscription_qos(spec), raw=True)
        executor = light_executor(ros_context)
        executor.add_node(self.node)
        self._spinner = Spinner(executor, 'live-relay')

    def follow_clock(self, sim_clock) -> None:
        """Stamp with the simulated rig's time (a SharedSimClock) instead of the wall's."""
        sim_clock.attach(self.node)

    @property
    def url(self) -> str:
        return f'ws://{self.host}:{self.port}'

    def _relay(self, topic: str, channel):
        clock = self.node.get_clock()

        def relay(data: bytes) -> None:
            channel.log(bytes(data), log_time=clock.now().nanoseconds)
            self.relayed[topic] += 1
        return relay

    def close(self) -> None:
        """Stop serving, and say how many messages of each topic were passed on."""
        self._spinner.stop()
        self.node.destroy_node()
        self.server.stop()
        counts = ', '.join(f'{topic} {n}' for topic, n in self.relayed.items() if n)
        print(f'live view closed: relayed {counts or "no messages"}', flush=True)


__all__ = ['LiveError', 'LiveRelay', 'parse_address']

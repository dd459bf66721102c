"""``ros2 run tocontrol_ros reindex``: rewrite a killed recording as a complete MCAP file.

A recorder killed outright (``kill -9``, power loss) leaves an MCAP file without its summary,
indexes and footer: a streaming reader reads it up to the last complete record, but indexed
readers (mcap's ``make_reader(...).iter_messages``, ``rosbags``) refuse it. This tool reads
it with the streaming reader, stops at the first incomplete or damaged record, and writes
every message before it, with its schema, channel, times and sequence number, to a new file
in the recorder's layout (summary, indexes and the ``rosbag2`` metadata record), as
``ros2 bag reindex`` does for rosbag2. The input is never modified and the output never
overwrites a file.

Usage: ``reindex RECORDING.mcap [-o OUTPUT.mcap]`` (default output:
``RECORDING.reindexed.mcap``). Exit status 0 on success, 2 when the input cannot be read or
the output cannot be written.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader

from tocontrol_ros.recording import mcap_io

__all__ = ["ReindexResult", "reindex", "build_parser", "main"]


@dataclass(frozen=True)
class ReindexResult:
    """What :func:`reindex` recovered.

    Attributes
    ----------
    output : Path
    messages : int
        Messages written to the output.
    complete : bool
        True when the input ended cleanly (nothing was cut off).
    stopped_at : str
        Why reading stopped early (empty when complete).
    """

    output: Path
    messages: int
    complete: bool
    stopped_at: str


def _read(path: Path):
    """Yield the records of ``path`` that are complete; the last item says how it ended."""
    with open(path, "rb") as f:
        try:
            yield from StreamReader(f).records
        except Exception as exc:  # noqa: BLE001  (any damage ends the readable part)
            yield f"{type(exc).__name__}: {exc}"


def reindex(source, output=None) -> ReindexResult:
    """Rewrite the readable part of ``source`` as a complete recording at ``output``.

    Parameters
    ----------
    source : str or os.PathLike
        An MCAP recording, finished or not.
    output : str or os.PathLike, optional
        Default: ``<source stem>.reindexed.mcap`` next to it.

    Returns
    -------
    ReindexResult

    Raises
    ------
    McapIOError
        The source is not an MCAP file, or the output exists.
    OSError
        The source cannot be read or the output cannot be written.
    """
    source = Path(source)
    output = Path(output) if output is not None else source.with_name(
        source.stem + ".reindexed.mcap")
    with open(source, "rb") as f:
        if f.read(8) != b"\x89MCAP0\r\n":
            raise mcap_io.McapIOError(f"{source} is not an MCAP file (no MCAP magic)")
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    count = 0
    stopped = ""
    complete = False
    with mcap_io.RecordingWriter(output) as writer:
        for record in _read(source):
            if isinstance(record, str):
                stopped = record
                break
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
                schema = schemas.get(record.schema_id)
                if schema is None:
                    continue
                writer.add_topic(record.topic, schema.name,
                                 record.metadata.get("offered_qos_profiles", ""),
                                 record.metadata.get("topic_type_hash", ""),
                                 definition=schema.data.decode("utf-8"))
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or channel.topic not in writer.topics:
                    continue
                writer.write(channel.topic, record.data, record.log_time,
                             record.publish_time, record.sequence)
                count += 1
            elif type(record).__name__ == "Footer":
                complete = True
    if not complete and not stopped:
        stopped = "the file ends without a footer"
    return ReindexResult(output, count, complete, stopped)


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    parser = argparse.ArgumentParser(
        prog="reindex", description="Rewrite a recording that was cut off (recorder killed) "
        "as a complete MCAP file with summary and indexes, readable by indexed readers and "
        "rosbags. The input is not modified.")
    parser.add_argument("recording", type=Path, help="the .mcap file to recover")
    parser.add_argument("-o", "--output", type=Path, default=None,
                        help="output file (default: <recording>.reindexed.mcap); never "
                        "overwritten")
    return parser


def main(argv=None) -> int:
    """Recover a recording; print the output path and what was recovered. Exit status."""
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    try:
        result = reindex(args.recording, args.output)
    except (OSError, ValueError) as err:
        reason = f"{err.strerror}: {err.filename}" if isinstance(err, OSError) and \
            err.strerror else str(err)
        print(f"reindex: {reason}", file=sys.stderr)
        return 2
    how = "complete input" if result.complete else f"input cut off ({result.stopped_at})"
    print(f"{result.output}: {result.messages} messages ({how})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

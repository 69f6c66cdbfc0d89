"""Names used inside fnsi-lab MCAP recordings (topics, schemas, metadata, attachments).

One constants module, in the pattern of mcap's ``well_known.py``: writer, reader, recovery
and documentation all refer to these names, so a rename happens in one place.
See ``docs/recording-format.md`` for what each record holds.
"""

from __future__ import annotations

import zlib

#: MCAP header ``profile``: empty, i.e. no ROS profile (the schema is plain protobuf).
PROFILE = ""
#: Prefix of the MCAP header ``library`` string (the software version follows).
LIBRARY_PREFIX = "fnsi-lab"

# ---------------------------------------------------------------------------- topics
#: Sample blocks, one protobuf message per :class:`daq.block.Block`.
TOPIC_SAMPLES = "/fnsi_lab/samples"
#: :class:`daq.source.SourceEvent` records (JSON).
TOPIC_EVENTS = "/fnsi_lab/events"

# ---------------------------------------------------------------------------- schemas
#: Fully qualified protobuf message name of a sample block.
SAMPLES_SCHEMA_NAME = "fnsi_lab.SampleBlock"
#: Name of the ``.proto`` file inside the schema's FileDescriptorSet.
SAMPLES_PROTO_FILE = "fnsi_lab/sample_block.proto"
#: Protobuf package of the schema.
PROTO_PACKAGE = "fnsi_lab"
#: Name of the JSON schema of the events topic.
EVENTS_SCHEMA_NAME = "fnsi_lab.SourceEvent"
#: Name of the (permissive) JSON schema shared by auxiliary topics of :meth:`Recorder.write_json`.
AUX_JSON_SCHEMA_NAME = "fnsi_lab.AuxJson"

# ---------------------------------------------------------------------------- encodings
SCHEMA_ENCODING_PROTOBUF = "protobuf"
SCHEMA_ENCODING_JSONSCHEMA = "jsonschema"
MESSAGE_ENCODING_PROTOBUF = "protobuf"
MESSAGE_ENCODING_JSON = "json"

# ---------------------------------------------------------------------------- channel metadata
#: Key of the MCAP channel metadata (of the samples topic) holding the channel table as a
#: JSON list of :meth:`daq.channels.ChannelInfo.to_dict`.
CHANNEL_META_CHANNELS = "channels"
#: Key of the MCAP channel metadata holding the nominal sample rate (decimal text, Hz).
CHANNEL_META_SAMPLE_RATE = "sample_rate_hz"
#: Key of the MCAP channel metadata holding the layout of ``data``.
CHANNEL_META_LAYOUT = "layout"
#: Value of :data:`CHANNEL_META_LAYOUT`.
LAYOUT_ROW_MAJOR = "row-major (n_samples, n_channels) float32"
#: Key of the MCAP channel metadata holding :data:`FORMAT_VERSION`.
CHANNEL_META_FORMAT = "fnsi_lab_format"
#: Version of this recording layout; bump on incompatible changes.
FORMAT_VERSION = "1"

# ---------------------------------------------------------------------------- metadata records
#: Every metadata key ``k`` is stored as the MCAP metadata record ``METADATA_PREFIX + k``.
METADATA_PREFIX = "fnsi_lab."
#: The single key inside each metadata record; its value is JSON text.
METADATA_JSON_KEY = "json"
#: CRC-32 (8 hex digits) of ``name + "\n" + json text`` in each metadata record: MCAP
#: metadata records carry no CRC of their own, so a flipped bit would go unnoticed.
METADATA_CRC_KEY = "crc32"
META_EXPERIMENT = "experiment"
META_CHANNELS = "channels"
META_EXCITATION = "excitation"
META_TRUTH = "truth"
META_SOURCE = "source"
#: Wall-clock origin of the message log times (``acquisition_start_utc_ns``).
META_CLOCK = "clock"
#: Key of the software version inside the ``experiment`` record (always written).
SOFTWARE_VERSION_KEY = "software_version"

# ---------------------------------------------------------------------------- attachments
#: The experiment YAML text, when the recording was made from a config file.
ATTACHMENT_EXPERIMENT_YAML = "experiment.yaml"
MEDIA_TYPE_YAML = "application/yaml"
MEDIA_TYPE_NPZ = "application/x-npz"


def metadata_record_name(key: str) -> str:
    """MCAP metadata record name of metadata key ``key`` (``fnsi_lab.<key>``)."""
    return METADATA_PREFIX + key


def metadata_crc(name: str, text: str) -> str:
    """CRC-32 of a metadata record's name and JSON text (``METADATA_CRC_KEY``), 8 hex digits."""
    return f"{zlib.crc32((name + chr(10) + text).encode()):08x}"

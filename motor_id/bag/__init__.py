"""MCAP recordings: a rosbag2-compatible writer, reading back to a Recording, info, recovery.

Layout of a motor_id bag (profile ``ros2``, CDR messages, ``ros2msg`` schemas holding the
complete message definitions, chunked and indexed, with a Statistics record and the
``rosbag2`` metadata record of a Jazzy bag, version 9; depths from motor_id.contracts):

==========================  ====================================  ===========================
topic                       type                                  QoS offered
==========================  ====================================  ===========================
``/samples``                std_msgs/msg/Float64MultiArray        reliable, volatile,
                                                                  SAMPLES_DEPTH
``/motor_id/meta``          std_msgs/msg/String (JSON)            reliable, transient local
``/identifier/estimate``    diagnostic_msgs/msg/DiagnosticArray   reliable, transient local
``/voltage`` ``/speed``     std_msgs/msg/Float64 (optional)       reliable, volatile,
``/current``                                                      CHANNEL_DEPTH
==========================  ====================================  ===========================

A ``/samples`` message is a batch of rows ``seq, t, voltage, speed, current, flags``
(:mod:`motor_id.contracts`, docs/CONTRACTS.md). Modules: ``schemas`` (types, CDR),
``profile`` (rosbag2 QoS and metadata record),
``writer`` (BagWriter, write_recording), ``reader`` (read_samples, read_meta,
read_recording; read_any_recording for any rosbag2 storage), ``anyreader`` (rosbags'
AnyReader and its errors), ``scan`` (the tolerant scan of damaged files), ``info``
(bag_info), ``recover``, ``files`` (finding and checking the file).
"""

from motor_id.bag.info import bag_info
from motor_id.bag.metadata import default_qos, qos_profile
from motor_id.bag.reader import (
    read_any_recording,
    read_meta,
    read_recording,
    read_samples,
    samples_recording,
    sorted_samples,
)
from motor_id.bag.recover import recover
from motor_id.bag.schemas import (
    DIAGNOSTIC_ARRAY,
    FLOAT64,
    FLOAT64_MULTI_ARRAY,
    message_definition,
    STRING,
    type_hash,
)
from motor_id.bag.writer import (
    BagWriter,
    COMPRESSIONS,
    DEFAULT_CHUNK_SIZE,
    DEFAULT_FLUSH_INTERVAL,
    library_string,
    write_recording,
)

__all__ = [
    'bag_info', 'BagWriter', 'COMPRESSIONS', 'DEFAULT_CHUNK_SIZE', 'DEFAULT_FLUSH_INTERVAL',
    'default_qos', 'DIAGNOSTIC_ARRAY', 'FLOAT64', 'FLOAT64_MULTI_ARRAY',
    'library_string', 'message_definition', 'qos_profile', 'read_any_recording', 'read_meta',
    'read_recording', 'read_samples', 'recover', 'samples_recording', 'sorted_samples',
    'STRING', 'type_hash', 'write_recording',
]

"""Sans-IO wire protocol of splitrender: control messages, framing, session state
machine, RTP/RTCP, H.264/H.265 payload formats, jitter buffer and SDP.

Nothing here touches sockets, threads or asyncio; see ``docs/protocol.md``.
"""

from splitrender.protocol.annexb import (
    START_CODE,
    Codec,
    contains_keyframe,
    is_keyframe_nal,
    join_annexb,
    nal_type,
    split_annexb,
)
from splitrender.protocol.connection import (
    TRANSITIONS,
    ClientConnection,
    Connection,
    Role,
    ServerConnection,
    State,
    check_auth_token,
    negotiate_method,
)
from splitrender.protocol.errors import (
    ErrorCode,
    FramingError,
    MessageError,
    PayloadError,
    RtcpError,
    RtpError,
    SdpError,
    StateError,
    TooLargeError,
    UnauthorizedError,
    UnsupportedMethodError,
    VersionError,
)
from splitrender.protocol.framing import (
    CONNECTION_CLOSED,
    FLAG_ZSTD,
    HEADER_SIZE,
    MAGIC,
    NEED_DATA,
    FrameDecoder,
    Sentinel,
    encode_frame,
)
from splitrender.protocol.h264 import h264_depayload, h264_payloads
from splitrender.protocol.h265 import h265_depayload, h265_payloads
from splitrender.protocol.jitter import AccessUnit, JitterBuffer
from splitrender.protocol.messages import (
    MAX_BODY_SIZE,
    MESSAGE_CLASSES,
    PROTOCOL_VERSION,
    Bye,
    DataChunk,
    Error,
    Feedback,
    FrameMeta,
    Hello,
    KeyframeRequest,
    Message,
    MessageType,
    Pose,
    Stats,
    StreamDescription,
    Welcome,
    decode_message,
)
from splitrender.protocol.packetizer import DEFAULT_MTU, RtpPacketizer, depacketize, payloads_for
from splitrender.protocol.rtcp import (
    GenericNack,
    KeyframeRateLimiter,
    PictureLossIndication,
    FullIntraRequest,
    ReceiverReport,
    ReceiverStatistics,
    ReportBlock,
    RetransmissionHistory,
    RtcpPacket,
    RtcpUnknown,
    SdesChunk,
    SenderReport,
    SourceDescription,
    compound_feedback,
    ntp_from_seconds,
    ntp_middle32,
    parse_rtcp,
    serialize_rtcp,
)
from splitrender.protocol.rtp import RtpPacket, SequenceUnwrapper, is_rtcp, seq_add, seq_diff, seq_lt
from splitrender.protocol.sdp import make_sdp, parameter_sets_from_sdp, parse_fmtp, sdp_attributes
from splitrender.protocol.sps import H264Sps, HevcSps, parse_h264_sps, parse_hevc_sps

__all__ = [
    # messages / framing / session
    "PROTOCOL_VERSION", "MessageType", "MAX_BODY_SIZE", "MESSAGE_CLASSES", "Message",
    "Hello", "Welcome", "StreamDescription", "Pose", "FrameMeta", "Feedback",
    "KeyframeRequest", "Stats", "Bye", "Error", "DataChunk", "decode_message",
    "MAGIC", "HEADER_SIZE", "FLAG_ZSTD", "NEED_DATA", "CONNECTION_CLOSED", "Sentinel",
    "encode_frame", "FrameDecoder",
    "Role", "State", "TRANSITIONS", "Connection", "ClientConnection", "ServerConnection",
    "check_auth_token", "negotiate_method",
    # errors
    "ErrorCode", "FramingError", "TooLargeError", "VersionError", "MessageError", "StateError",
    "UnauthorizedError", "UnsupportedMethodError", "RtpError", "RtcpError", "PayloadError",
    "SdpError",
    # RTP / payload formats
    "RtpPacket", "SequenceUnwrapper", "seq_add", "seq_diff", "seq_lt", "is_rtcp",
    "Codec", "START_CODE", "split_annexb", "join_annexb", "nal_type", "is_keyframe_nal",
    "contains_keyframe", "h264_payloads", "h264_depayload", "h265_payloads", "h265_depayload",
    "DEFAULT_MTU", "RtpPacketizer", "payloads_for", "depacketize",
    "AccessUnit", "JitterBuffer",
    # RTCP
    "ReportBlock", "SenderReport", "ReceiverReport", "GenericNack", "PictureLossIndication", "FullIntraRequest",
    "RtcpUnknown", "RtcpPacket", "SdesChunk", "SourceDescription", "compound_feedback",
    "parse_rtcp", "serialize_rtcp", "ntp_from_seconds",
    "ntp_middle32", "ReceiverStatistics", "RetransmissionHistory", "KeyframeRateLimiter",
    # SDP
    "make_sdp", "parse_fmtp", "parameter_sets_from_sdp", "sdp_attributes",
    "H264Sps", "HevcSps", "parse_h264_sps", "parse_hevc_sps",
]

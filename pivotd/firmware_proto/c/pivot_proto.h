/*
 * pivot_proto: C99 codec of the pivotd gimbal serial protocol (see ../PROTOCOL.md).
 *
 * Frame on the wire: COBS(body) 0x00, body = version | type | seq | payload | crc16 (little-endian),
 * CRC-16/CCITT-FALSE over version..payload. No dynamic memory, no stdio: suitable for firmware.
 * All angles are int32 micro-radians, rates micro-rad/s, accelerations micro-rad/s^2.
 */
#ifndef PIVOT_PROTO_H
#define PIVOT_PROTO_H

#include <stddef.h>
#include <stdint.h>

#define PP_VERSION 2u
#define PP_MAX_BODY 64u
#define PP_MAX_ENCODED (PP_MAX_BODY + 1u) /* COBS adds one byte per 254 */
#define PP_MAX_FRAME (PP_MAX_ENCODED + 1u) /* plus the 0x00 delimiter */

enum pp_type {
    PP_HELLO = 0x01, PP_CONFIG = 0x02, PP_ENABLE = 0x03, PP_SETPOINT = 0x04, PP_HEARTBEAT = 0x05,
    PP_CLEAR_FAULT = 0x06, PP_STATE = 0x40, PP_IDENTITY = 0x41, PP_ACK = 0x42
};

enum pp_mode { PP_MODE_DISABLED = 0, PP_MODE_ENABLED = 1, PP_MODE_HOLDING = 2, PP_MODE_FAULT = 3 };

enum pp_fault_bit {
    PP_FAULT_OVERCURRENT = 1u << 0, PP_FAULT_OVERTEMP = 1u << 1, PP_FAULT_ENCODER = 1u << 2,
    PP_FAULT_DRIVER = 1u << 3, PP_FAULT_WATCHDOG = 1u << 4, PP_FAULT_CLAMPED = 1u << 5,
    PP_FAULT_CONFIG = 1u << 6, PP_FAULT_UNDERVOLTAGE = 1u << 7
};

enum pp_ack_status {
    PP_ACK_OK = 0, PP_NACK_CONFIG_INVALID = 1, PP_NACK_NOT_CONFIGURED = 2, PP_NACK_FAULT_ACTIVE = 3,
    PP_NACK_BAD_VALUE = 4
};

/* Drop reasons of the stream decoder (same order and meaning as the Python decoder). */
enum pp_drop { PP_DROP_FRAMING = 0, PP_DROP_LENGTH, PP_DROP_CRC, PP_DROP_VERSION, PP_DROP_UNKNOWN_TYPE,
               PP_DROP_PAYLOAD, PP_DROP_COUNT };

typedef struct { uint8_t host_version; } pp_hello;
typedef struct {
    int32_t pan_min, pan_max, tilt_min, tilt_max, vmax_pan, vmax_tilt, amax_pan, amax_tilt;
    uint16_t watchdog_ms;
} pp_config;
typedef struct { uint8_t on; } pp_enable;
/* SETPOINT (version 2): state_time_us echoes the device_time_us of the newest STATE the host had, max_age_ms is
 * the validity: the device executes it only while pp_setpoint_fresh() (see ../PROTOCOL.md section 4). */
typedef struct {
    int32_t pan, tilt, pan_rate, tilt_rate;
    uint32_t host_time_us, state_time_us;
    uint16_t max_age_ms;
} pp_setpoint;
typedef struct {
    uint32_t device_time_us;
    int32_t pan, tilt, pan_rate, tilt_rate;
    uint8_t last_setpoint_seq, mode;
    uint16_t faults;
} pp_state;
typedef struct { uint8_t version, fw_major, fw_minor, fw_patch; uint32_t capabilities, serial; } pp_identity;
typedef struct { uint8_t acked_seq, acked_type, status; uint32_t value; } pp_ack;

/* One message: header fields plus the payload of its type. */
typedef struct {
    uint8_t version, type, seq;
    union {
        pp_hello hello; pp_config config; pp_enable enable; pp_setpoint setpoint;
        pp_state state; pp_identity identity; pp_ack ack;
    } u;
} pp_msg;

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF); pp_crc16("123456789") == 0x29B1. */
uint16_t pp_crc16(const uint8_t *data, size_t len);

/* COBS encode len bytes; returns the encoded length, or 0 if cap is too small. */
size_t pp_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap);
/* COBS decode (input without delimiter); returns 0 and sets *out_len, or -1 on invalid input/overflow. */
int pp_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len);

/* Payload length of a message type, or -1 for an unknown type. */
int pp_payload_len(uint8_t type);
/* Pack m's payload into out (at least PP_MAX_BODY bytes); returns its length or -1 for an unknown type. */
int pp_pack_payload(const pp_msg *m, uint8_t *out);
/* Unpack a payload of the given type into m->u; returns 0, or PP_DROP_UNKNOWN_TYPE / PP_DROP_PAYLOAD + 1. */
int pp_unpack_payload(uint8_t type, const uint8_t *payload, size_t len, pp_msg *m);

/* Encode a complete frame (COBS + delimiter) into out; returns its length or 0 on error. */
size_t pp_encode_frame(const pp_msg *m, uint8_t *out, size_t cap);
/* Decode one body (after COBS); returns -1 if valid (m filled) or the pp_drop reason. */
int pp_decode_body(const uint8_t *body, size_t len, pp_msg *m);

/* Age [us] on the device clock of a SETPOINT echoing the STATE stamped state_time_us: modulo 2^32 (the clock
 * wraps), so a stamp from the future reads as very old. */
uint32_t pp_setpoint_age_us(uint32_t device_time_us, uint32_t state_time_us);
/* 1 if the device may execute s at device_time_us (age <= max_age_ms), 0 if it is stale: drop it (count it) and
 * leave mode, targets, watchdog and last_setpoint_seq as they are. */
int pp_setpoint_fresh(const pp_setpoint *s, uint32_t device_time_us);

/* Byte-at-a-time stream decoder with a fixed buffer; resyncs on 0x00. */
typedef struct {
    uint8_t buf[PP_MAX_ENCODED];
    size_t len;
    int discarding;
    uint32_t frames_ok;
    uint32_t drops[PP_DROP_COUNT];
} pp_decoder;

void pp_decoder_init(pp_decoder *d);
/* Push one received byte; returns 1 when it completed a valid frame (written to *out), else 0. */
int pp_decoder_push(pp_decoder *d, uint8_t byte, pp_msg *out);

#endif /* PIVOT_PROTO_H */

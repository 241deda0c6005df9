/* pivot_proto: C99 codec of the pivotd gimbal serial protocol (see pivot_proto.h, ../PROTOCOL.md). */
#include "pivot_proto.h"

uint16_t pp_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    int bit;
    for (i = 0; i < len; i++) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (bit = 0; bit < 8; bit++) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

size_t pp_cobs_encode(const uint8_t *in, size_t len, uint8_t *out, size_t cap)
{
    size_t code_pos = 0, o = 1, i;
    uint8_t code = 1;
    if (cap < 1) return 0;
    for (i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_pos] = code;
            code_pos = o++;
            code = 1;
            if (code_pos >= cap) return 0;
        } else {
            if (o >= cap) return 0;
            out[o++] = in[i];
            code++;
            if (code == 0xFF) {
                out[code_pos] = code;
                code_pos = o++;
                code = 1;
                if (code_pos >= cap) return 0;
            }
        }
    }
    out[code_pos] = code;
    return o;
}

int pp_cobs_decode(const uint8_t *in, size_t len, uint8_t *out, size_t cap, size_t *out_len)
{
    size_t i = 0, o = 0, j;
    while (i < len) {
        uint8_t code = in[i++];
        if (code == 0) return -1;
        if (i + (size_t)(code - 1) > len) return -1;
        for (j = 1; j < code; j++) {
            if (in[i] == 0 || o >= cap) return -1;
            out[o++] = in[i++];
        }
        if (code != 0xFF && i < len) {
            if (o >= cap) return -1;
            out[o++] = 0;
        }
    }
    *out_len = o;
    return 0;
}

static void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static void put_i32(uint8_t *p, int32_t v) { put_u32(p, (uint32_t)v); }
static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static int32_t get_i32(const uint8_t *p)
{
    uint32_t u = get_u32(p);
    return (u & 0x80000000u) ? (int32_t)(-(int64_t)(~u) - 1) : (int32_t)u;
}

int pp_payload_len(uint8_t type)
{
    switch (type) {
    case PP_HELLO: return 1;
    case PP_CONFIG: return 34;
    case PP_ENABLE: return 1;
    case PP_SETPOINT: return 26;
    case PP_HEARTBEAT: return 0;
    case PP_CLEAR_FAULT: return 0;
    case PP_STATE: return 24;
    case PP_IDENTITY: return 12;
    case PP_ACK: return 7;
    default: return -1;
    }
}

int pp_pack_payload(const pp_msg *m, uint8_t *p)
{
    switch (m->type) {
    case PP_HELLO: p[0] = m->u.hello.host_version; break;
    case PP_CONFIG: {
        const pp_config *c = &m->u.config;
        put_i32(p, c->pan_min); put_i32(p + 4, c->pan_max); put_i32(p + 8, c->tilt_min);
        put_i32(p + 12, c->tilt_max); put_i32(p + 16, c->vmax_pan); put_i32(p + 20, c->vmax_tilt);
        put_i32(p + 24, c->amax_pan); put_i32(p + 28, c->amax_tilt); put_u16(p + 32, c->watchdog_ms);
        break;
    }
    case PP_ENABLE: p[0] = m->u.enable.on; break;
    case PP_SETPOINT: {
        const pp_setpoint *s = &m->u.setpoint;
        put_i32(p, s->pan); put_i32(p + 4, s->tilt); put_i32(p + 8, s->pan_rate); put_i32(p + 12, s->tilt_rate);
        put_u32(p + 16, s->host_time_us); put_u32(p + 20, s->state_time_us); put_u16(p + 24, s->max_age_ms);
        break;
    }
    case PP_HEARTBEAT: case PP_CLEAR_FAULT: break;
    case PP_STATE: {
        const pp_state *s = &m->u.state;
        put_u32(p, s->device_time_us); put_i32(p + 4, s->pan); put_i32(p + 8, s->tilt);
        put_i32(p + 12, s->pan_rate); put_i32(p + 16, s->tilt_rate);
        p[20] = s->last_setpoint_seq; p[21] = s->mode; put_u16(p + 22, s->faults);
        break;
    }
    case PP_IDENTITY: {
        const pp_identity *s = &m->u.identity;
        p[0] = s->version; p[1] = s->fw_major; p[2] = s->fw_minor; p[3] = s->fw_patch;
        put_u32(p + 4, s->capabilities); put_u32(p + 8, s->serial);
        break;
    }
    case PP_ACK: {
        const pp_ack *a = &m->u.ack;
        p[0] = a->acked_seq; p[1] = a->acked_type; p[2] = a->status; put_u32(p + 3, a->value);
        break;
    }
    default: return -1;
    }
    return pp_payload_len(m->type);
}

int pp_unpack_payload(uint8_t type, const uint8_t *p, size_t len, pp_msg *m)
{
    int want = pp_payload_len(type);
    if (want < 0) return PP_DROP_UNKNOWN_TYPE + 1;
    if ((size_t)want != len) return PP_DROP_PAYLOAD + 1;
    m->type = type;
    switch (type) {
    case PP_HELLO: m->u.hello.host_version = p[0]; break;
    case PP_CONFIG: {
        pp_config *c = &m->u.config;
        c->pan_min = get_i32(p); c->pan_max = get_i32(p + 4); c->tilt_min = get_i32(p + 8);
        c->tilt_max = get_i32(p + 12); c->vmax_pan = get_i32(p + 16); c->vmax_tilt = get_i32(p + 20);
        c->amax_pan = get_i32(p + 24); c->amax_tilt = get_i32(p + 28); c->watchdog_ms = get_u16(p + 32);
        break;
    }
    case PP_ENABLE: m->u.enable.on = p[0]; break;
    case PP_SETPOINT: {
        pp_setpoint *s = &m->u.setpoint;
        s->pan = get_i32(p); s->tilt = get_i32(p + 4); s->pan_rate = get_i32(p + 8); s->tilt_rate = get_i32(p + 12);
        s->host_time_us = get_u32(p + 16); s->state_time_us = get_u32(p + 20); s->max_age_ms = get_u16(p + 24);
        break;
    }
    case PP_STATE: {
        pp_state *s = &m->u.state;
        s->device_time_us = get_u32(p); s->pan = get_i32(p + 4); s->tilt = get_i32(p + 8);
        s->pan_rate = get_i32(p + 12); s->tilt_rate = get_i32(p + 16);
        s->last_setpoint_seq = p[20]; s->mode = p[21]; s->faults = get_u16(p + 22);
        break;
    }
    case PP_IDENTITY: {
        pp_identity *s = &m->u.identity;
        s->version = p[0]; s->fw_major = p[1]; s->fw_minor = p[2]; s->fw_patch = p[3];
        s->capabilities = get_u32(p + 4); s->serial = get_u32(p + 8);
        break;
    }
    case PP_ACK: {
        pp_ack *a = &m->u.ack;
        a->acked_seq = p[0]; a->acked_type = p[1]; a->status = p[2]; a->value = get_u32(p + 3);
        break;
    }
    default: break; /* HEARTBEAT, CLEAR_FAULT: empty */
    }
    return 0;
}

size_t pp_encode_frame(const pp_msg *m, uint8_t *out, size_t cap)
{
    uint8_t body[PP_MAX_BODY];
    int n = pp_payload_len(m->type);
    size_t len, enc;
    uint16_t crc;
    if (n < 0 || (size_t)n + 5u > PP_MAX_BODY) return 0;
    body[0] = m->version; body[1] = m->type; body[2] = m->seq;
    pp_pack_payload(m, body + 3);
    len = 3u + (size_t)n;
    crc = pp_crc16(body, len);
    put_u16(body + len, crc);
    len += 2u;
    if (cap < 2) return 0;
    enc = pp_cobs_encode(body, len, out, cap - 1u);
    if (enc == 0) return 0;
    out[enc] = 0;
    return enc + 1u;
}

int pp_decode_body(const uint8_t *body, size_t len, pp_msg *m)
{
    int rc;
    if (len < 5u || len > PP_MAX_BODY) return PP_DROP_LENGTH;
    if (pp_crc16(body, len - 2u) != get_u16(body + len - 2u)) return PP_DROP_CRC;
    /* HELLO and IDENTITY have layouts frozen across versions: accepted whatever the version */
    if (body[0] != PP_VERSION && body[1] != PP_HELLO && body[1] != PP_IDENTITY) return PP_DROP_VERSION;
    rc = pp_unpack_payload(body[1], body + 3, len - 5u, m);
    if (rc != 0) return rc - 1;
    m->version = body[0];
    m->seq = body[2];
    return -1;
}

uint32_t pp_setpoint_age_us(uint32_t device_time_us, uint32_t state_time_us)
{
    return (uint32_t)(device_time_us - state_time_us);
}

int pp_setpoint_fresh(const pp_setpoint *s, uint32_t device_time_us)
{
    return pp_setpoint_age_us(device_time_us, s->state_time_us) <= (uint32_t)s->max_age_ms * 1000u;
}

void pp_decoder_init(pp_decoder *d)
{
    size_t i;
    d->len = 0;
    d->discarding = 0;
    d->frames_ok = 0;
    for (i = 0; i < PP_DROP_COUNT; i++) d->drops[i] = 0;
}

int pp_decoder_push(pp_decoder *d, uint8_t byte, pp_msg *out)
{
    uint8_t body[PP_MAX_BODY];
    size_t n = 0;
    int reason;
    if (byte != 0) {
        if (d->discarding) return 0;
        if (d->len >= PP_MAX_ENCODED) { /* no delimiter within a maximal frame: drop until the next one */
            d->drops[PP_DROP_LENGTH]++;
            d->discarding = 1;
            d->len = 0;
            return 0;
        }
        d->buf[d->len++] = byte;
        return 0;
    }
    if (d->discarding || d->len == 0) {
        d->discarding = 0;
        d->len = 0;
        return 0;
    }
    if (pp_cobs_decode(d->buf, d->len, body, sizeof body, &n) != 0) {
        d->len = 0;
        d->drops[PP_DROP_FRAMING]++;
        return 0;
    }
    d->len = 0;
    reason = pp_decode_body(body, n, out);
    if (reason >= 0) {
        d->drops[reason]++;
        return 0;
    }
    d->frames_ok++;
    return 1;
}

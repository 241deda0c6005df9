/* Host test program: checks the C codec against every vector of ../vectors.json (via pp_vectors.h). */
#include <stdio.h>
#include <string.h>

#include "pivot_proto.h"
#include "pp_vectors.h"

static int failures = 0;

#define CHECK(cond, name, what)                                              \
    do {                                                                     \
        if (!(cond)) {                                                       \
            printf("FAIL %s: %s\n", (name), (what));                         \
            failures++;                                                      \
        }                                                                    \
    } while (0)

/* Message fields <-> the vectors' flat raw[] arrays, in wire order. */
static void fill(pp_msg *m, uint8_t type, const int64_t *r)
{
    memset(m, 0, sizeof *m);
    m->type = type;
    m->version = PP_VERSION;
    switch (type) {
    case PP_HELLO: m->u.hello.host_version = (uint8_t)r[0]; break;
    case PP_CONFIG:
        m->u.config.pan_min = (int32_t)r[0]; m->u.config.pan_max = (int32_t)r[1];
        m->u.config.tilt_min = (int32_t)r[2]; m->u.config.tilt_max = (int32_t)r[3];
        m->u.config.vmax_pan = (int32_t)r[4]; m->u.config.vmax_tilt = (int32_t)r[5];
        m->u.config.amax_pan = (int32_t)r[6]; m->u.config.amax_tilt = (int32_t)r[7];
        m->u.config.watchdog_ms = (uint16_t)r[8];
        break;
    case PP_ENABLE: m->u.enable.on = (uint8_t)r[0]; break;
    case PP_SETPOINT:
        m->u.setpoint.pan = (int32_t)r[0]; m->u.setpoint.tilt = (int32_t)r[1];
        m->u.setpoint.pan_rate = (int32_t)r[2]; m->u.setpoint.tilt_rate = (int32_t)r[3];
        m->u.setpoint.host_time_us = (uint32_t)r[4]; m->u.setpoint.state_time_us = (uint32_t)r[5];
        m->u.setpoint.max_age_ms = (uint16_t)r[6];
        break;
    case PP_STATE:
        m->u.state.device_time_us = (uint32_t)r[0]; m->u.state.pan = (int32_t)r[1];
        m->u.state.tilt = (int32_t)r[2]; m->u.state.pan_rate = (int32_t)r[3];
        m->u.state.tilt_rate = (int32_t)r[4]; m->u.state.last_setpoint_seq = (uint8_t)r[5];
        m->u.state.mode = (uint8_t)r[6]; m->u.state.faults = (uint16_t)r[7];
        break;
    case PP_IDENTITY:
        m->u.identity.version = (uint8_t)r[0]; m->u.identity.fw_major = (uint8_t)r[1];
        m->u.identity.fw_minor = (uint8_t)r[2]; m->u.identity.fw_patch = (uint8_t)r[3];
        m->u.identity.capabilities = (uint32_t)r[4]; m->u.identity.serial = (uint32_t)r[5];
        break;
    case PP_ACK:
        m->u.ack.acked_seq = (uint8_t)r[0]; m->u.ack.acked_type = (uint8_t)r[1];
        m->u.ack.status = (uint8_t)r[2]; m->u.ack.value = (uint32_t)r[3];
        break;
    default: break;
    }
}

static int same_fields(const pp_msg *a, const pp_msg *b)
{
    uint8_t pa[PP_MAX_BODY], pb[PP_MAX_BODY];
    int na = pp_pack_payload(a, pa), nb = pp_pack_payload(b, pb);
    return a->type == b->type && na == nb && na >= 0 && memcmp(pa, pb, (size_t)na) == 0;
}

int main(void)
{
    size_t i, k, nf = sizeof PP_FRAME_VECTORS / sizeof PP_FRAME_VECTORS[0];
    size_t ns = sizeof PP_STREAM_VECTORS / sizeof PP_STREAM_VECTORS[0];
    size_t nv = sizeof PP_VALIDITY_VECTORS / sizeof PP_VALIDITY_VECTORS[0];
    size_t checked = 0;
    CHECK(pp_crc16((const uint8_t *)"123456789", 9) == PP_CRC_CHECK, "crc_check", "CRC of 123456789");

    for (i = 0; i < nf; i++) {
        const pp_frame_vector *v = &PP_FRAME_VECTORS[i];
        pp_msg want, got;
        pp_decoder dec;
        uint8_t out[PP_MAX_FRAME + 8];
        size_t n;
        int frames = 0;
        fill(&want, v->type, v->raw);
        want.seq = v->seq;
        n = pp_encode_frame(&want, out, sizeof out);
        CHECK(n == v->frame_len && memcmp(out, v->frame, n) == 0, v->name, "encoded bytes differ");
        pp_decoder_init(&dec);
        for (k = 0; k < v->frame_len; k++) frames += pp_decoder_push(&dec, v->frame[k], &got);
        CHECK(frames == 1, v->name, "decoder did not yield exactly one frame");
        CHECK(frames == 1 && got.seq == v->seq && got.version == PP_VERSION && same_fields(&want, &got), v->name,
              "decoded fields differ");
        checked++;
    }

    for (i = 0; i < ns; i++) {
        const pp_stream_vector *s = &PP_STREAM_VECTORS[i];
        pp_decoder dec;
        pp_msg got, want;
        size_t nframes = 0;
        pp_decoder_init(&dec);
        for (k = 0; k < s->stream_len; k++) {
            if (pp_decoder_push(&dec, s->stream[k], &got)) {
                if (nframes < s->nframes) {
                    const pp_expected_frame *e = &s->frames[nframes];
                    fill(&want, e->type, e->raw);
                    CHECK(got.seq == e->seq && got.version == e->version && same_fields(&want, &got), s->name,
                          "stream frame differs");
                }
                nframes++;
            }
        }
        CHECK(nframes == s->nframes, s->name, "wrong number of frames");
        for (k = 0; k < PP_DROP_COUNT; k++) CHECK(dec.drops[k] == s->drops[k], s->name, "drop counter differs");
        checked++;
    }

    for (i = 0; i < nv; i++) {
        const pp_validity_vector *c = &PP_VALIDITY_VECTORS[i];
        pp_setpoint sp;
        memset(&sp, 0, sizeof sp);
        sp.state_time_us = c->state_time_us;
        sp.max_age_ms = c->max_age_ms;
        CHECK(pp_setpoint_age_us(c->device_time_us, c->state_time_us) == c->age_us, c->name, "setpoint age differs");
        CHECK(pp_setpoint_fresh(&sp, c->device_time_us) == c->fresh, c->name, "setpoint validity differs");
        checked++;
    }

    printf("%s: %zu vectors checked, %d failures\n", failures ? "FAIL" : "OK", checked, failures);
    return failures ? 1 : 0;
}

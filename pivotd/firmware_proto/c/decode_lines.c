/*
 * Differential-test driver: each stdin line is a hex-encoded byte stream; for each line, print the
 * frames the C stream decoder yields ("F type seq version payload-hex") and then its drop counters
 * ("D framing length crc version unknown_type payload").
 */
#include <stdio.h>
#include <string.h>

#include "pivot_proto.h"

static int hexval(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int main(void)
{
    static char line[65536];
    while (fgets(line, sizeof line, stdin) != NULL) {
        pp_decoder dec;
        pp_msg m;
        size_t i, k, n = strlen(line);
        pp_decoder_init(&dec);
        for (i = 0; i + 1 < n; i += 2) {
            int hi = hexval((unsigned char)line[i]), lo = hexval((unsigned char)line[i + 1]);
            if (hi < 0 || lo < 0) break;
            if (pp_decoder_push(&dec, (uint8_t)(hi * 16 + lo), &m)) {
                uint8_t payload[PP_MAX_BODY];
                int len = pp_pack_payload(&m, payload);
                printf("F %u %u %u ", m.type, m.seq, m.version);
                for (k = 0; k < (size_t)len; k++) printf("%02x", payload[k]);
                printf("\n");
            }
        }
        printf("D");
        for (k = 0; k < PP_DROP_COUNT; k++) printf(" %lu", (unsigned long)dec.drops[k]);
        printf("\n");
    }
    return 0;
}

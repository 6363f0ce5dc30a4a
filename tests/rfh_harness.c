/*
 * Test harness of the C reference (tests/test_c_reference.py builds it with ASan and UBSan).
 *
 * stdin: inputs, each a 4-byte little-endian length and that many bytes. Each input goes
 * byte by byte through a fresh decoder; stdout gets one line per input, one word per frame end:
 *   D<n>      dropped, n = rfh_drop_t
 *   T<hex>    a checked frame of an unknown type (its inner bytes)
 *   L<hex>    a checked frame its type's parser rejects
 *   F<hex>    parsed, then encoded again by the C encoder: the whole frame on the wire
 */
#include <stdio.h>
#include <stdlib.h>

#include "rfh_frames.h"

static void hex(char tag, const uint8_t *b, size_t n)
{
    size_t i;
    putchar(tag);
    for (i = 0; i < n; ++i) {
        printf("%02x", b[i]);
    }
    putchar(' ');
}

/* Parse the decoder's frame with its type's parser and encode it again; 0: parser refused. */
static size_t reencode(const rfh_decoder_t *dec, uint8_t *out, size_t cap, int *known)
{
    size_t len;
    const uint8_t *b = rfh_decoder_body(dec, &len);
    const rfh_header_t *h = &dec->header;
    *known = 1;
    switch (dec->type) {
    case 0x01: { rfh_adv_report_t r; return rfh_parse_adv_report(b, len, &r) ? rfh_encode_adv_report(out, cap, h, &r) : 0; }
    case 0x02: { rfh_rf_frame_t r; return rfh_parse_rf_frame(b, len, &r) ? rfh_encode_rf_frame(out, cap, h, &r) : 0; }
    case 0x03: { rfh_antenna_set_t r; return rfh_parse_antenna_set(b, len, &r) ? rfh_encode_antenna_set(out, cap, h, &r) : 0; }
    case 0x10: { rfh_status_t r; return rfh_parse_status(b, len, &r) ? rfh_encode_status(out, cap, h, &r) : 0; }
    case 0x20: { rfh_odometry_t r; return rfh_parse_odometry(b, len, &r) ? rfh_encode_odometry(out, cap, h, &r) : 0; }
    case 0x21: {
        rfh_velocity_command_t r;
        return rfh_parse_velocity_command(b, len, &r) ? rfh_encode_velocity_command(out, cap, h, &r) : 0;
    }
    case 0x22: {
        rfh_range_scan_t r;
        const uint8_t *le;
        uint16_t ranges[256];
        size_t i;
        if (!rfh_parse_range_scan(b, len, &r, &le)) {
            return 0;
        }
        for (i = 0; i < r.count; ++i) {
            ranges[i] = (uint16_t)(le[2 * i] | (le[2 * i + 1] << 8));
        }
        r.ranges_mm = ranges;
        return rfh_encode_range_scan(out, cap, h, &r);
    }
    case 0x23: {
        rfh_range_scan_v2_t r;
        const uint8_t *le;
        uint16_t ranges[256];
        size_t i;
        if (!rfh_parse_range_scan_v2(b, len, &r, &le)) {
            return 0;
        }
        for (i = 0; i < r.count; ++i) {
            ranges[i] = (uint16_t)(le[2 * i] | (le[2 * i + 1] << 8));
        }
        r.ranges_mm = ranges;
        return rfh_encode_range_scan_v2(out, cap, h, &r);
    }
    case 0x7F: { rfh_log_text_t r; return rfh_parse_log_text(b, len, &r) ? rfh_encode_log_text(out, cap, h, &r) : 0; }
    case 0x80: { rfh_node_command_t r; return rfh_parse_node_command(b, len, &r) ? rfh_encode_node_command(out, cap, h, &r) : 0; }
    default:
        *known = 0;
        return 0;
    }
}

int main(void)
{
    static rfh_decoder_t dec;
    static uint8_t frame[RFH_MAX_FRAME];
    unsigned char size[4];
    while (fread(size, 1, 4, stdin) == 4) {
        size_t n = size[0] | (size[1] << 8) | ((size_t)size[2] << 16) | ((size_t)size[3] << 24), i;
        rfh_decoder_init(&dec);
        for (i = 0; i < n; ++i) {
            int c = getchar(), known;
            rfh_dec_result_t res;
            size_t m;
            if (c == EOF) {
                return 2;
            }
            res = rfh_decoder_feed(&dec, (uint8_t)c);
            if (res == RFH_DEC_DROP) {
                printf("D%d ", (int)dec.drop);
            } else if (res == RFH_DEC_FRAME) {
                m = reencode(&dec, frame, sizeof frame, &known);
                if (m) {
                    hex('F', frame, m);
                } else {
                    hex(known ? 'L' : 'T', dec.inner, dec.inner_len);
                }
            }
        }
        putchar('\n');
    }
    return 0;
}

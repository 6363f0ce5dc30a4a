/*
 * rfh_frames.c -- encoder and decoder of rfhoming's binary records (see rfh_frames.h).
 *
 * The encoder streams: every byte of header and body goes through the CRC and straight into
 * the COBS encoder, which writes into the caller's buffer, so no inner frame is ever buffered.
 * Its COBS output is byte-for-byte that of Python's `cobs` package (a data run that ends
 * exactly at a full 254-byte block gets no trailing 0x01 code).
 */
#include "rfh_frames.h"

#include <string.h>

uint16_t rfh_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    int bit;
    for (i = 0; i < len; ++i) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (bit = 0; bit < 8; ++bit) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

/* ---- streaming COBS writer ------------------------------------------------------------- */

typedef struct {
    uint8_t *out;
    size_t cap;
    size_t len;      /* bytes written so far, reserved code slot included */
    size_t code_at;  /* where the current block's code byte goes */
    uint8_t code;
    int pending;     /* a full block was closed; the next byte opens a new one */
    uint16_t crc;
    size_t inner;    /* inner bytes so far */
    int fail;
} writer_t;

static int w_room(writer_t *w)
{
    /* one byte more must always fit: the closing zero */
    if (w->len + 1u >= w->cap) {
        w->fail = 1;
    }
    return !w->fail;
}

static void w_cobs(writer_t *w, uint8_t b)
{
    if (w->fail) {
        return;
    }
    if (w->pending) {
        if (!w_room(w)) {
            return;
        }
        w->code_at = w->len++;
        w->code = 1;
        w->pending = 0;
    }
    if (!w_room(w)) {
        return;
    }
    if (b != 0) {
        w->out[w->len++] = b;
        if (++w->code == 0xFFu) {
            w->out[w->code_at] = 0xFFu;
            w->pending = 1;
        }
    } else {
        w->out[w->code_at] = w->code;
        w->code_at = w->len++;
        w->code = 1;
    }
}

static void w_u8(writer_t *w, uint8_t b)
{
    uint8_t x = b;
    int bit;
    w->crc ^= (uint16_t)((uint16_t)x << 8);
    for (bit = 0; bit < 8; ++bit) {
        w->crc = (w->crc & 0x8000u) ? (uint16_t)((w->crc << 1) ^ 0x1021u) : (uint16_t)(w->crc << 1);
    }
    if (++w->inner > RFH_MAX_INNER - RFH_CRC_SIZE) {
        w->fail = 1;
    }
    w_cobs(w, b);
}

static void w_u16(writer_t *w, uint16_t v)
{
    w_u8(w, (uint8_t)(v & 0xFFu));
    w_u8(w, (uint8_t)(v >> 8));
}

static void w_u32(writer_t *w, uint32_t v)
{
    w_u16(w, (uint16_t)(v & 0xFFFFu));
    w_u16(w, (uint16_t)(v >> 16));
}

static void w_bytes(writer_t *w, const uint8_t *p, size_t n)
{
    size_t i;
    if (n != 0 && p == NULL) {
        w->fail = 1;
        return;
    }
    for (i = 0; i < n && !w->fail; ++i) {
        w_u8(w, p[i]);
    }
}

static void w_begin(writer_t *w, uint8_t *out, size_t cap, uint8_t type, const rfh_header_t *h)
{
    w->out = out;
    w->cap = cap;
    w->crc = 0xFFFFu;
    w->inner = 0;
    w->pending = 0;
    w->fail = (out == NULL || h == NULL || cap < 3u);
    if (w->fail) {
        return;
    }
    out[0] = 0;
    w->code_at = 1;
    w->len = 2;
    w->code = 1;
    w_u8(w, RFH_VERSION);
    w_u8(w, type);
    w_u8(w, h->node_id);
    w_u16(w, h->seq);
    w_u32(w, h->t_us);
}

static size_t w_end(writer_t *w)
{
    uint16_t crc = w->crc;
    w_cobs(w, (uint8_t)(crc & 0xFFu));
    w_cobs(w, (uint8_t)(crc >> 8));
    if (w->fail || w->len >= w->cap) {
        return 0;
    }
    if (!w->pending) {
        w->out[w->code_at] = w->code;
    }
    w->out[w->len++] = 0;
    return w->len;
}

/* ---- encoders ----------------------------------------------------------------------------- */

size_t rfh_encode_adv_report(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_adv_report_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_ADV_REPORT, h);
    if (r == NULL) {
        return 0;
    }
    w_bytes(&w, r->addr, 6);
    w_u8(&w, r->addr_type);
    w_u8(&w, r->adv_props);
    w_u8(&w, (uint8_t)r->rssi_dbm);
    w_u8(&w, (uint8_t)r->tx_power_dbm);
    w_u8(&w, r->channel);
    w_u8(&w, r->ad_len);
    w_bytes(&w, r->ad, r->ad_len);
    return w_end(&w);
}

size_t rfh_encode_rf_frame(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_rf_frame_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_RF_FRAME, h);
    if (r == NULL) {
        return 0;
    }
    w_u8(&w, r->antenna);
    w_u8(&w, r->channel);
    w_u8(&w, r->page);
    w_u8(&w, r->trx_ctrl_2);
    w_u8(&w, (uint8_t)r->rssi_base_dbm);
    w_u8(&w, r->ed);
    w_u8(&w, r->lqi);
    w_u8(&w, r->rx_status);
    w_u16(&w, r->emitter_seq);
    w_u8(&w, r->psdu_len);
    w_bytes(&w, r->psdu, r->psdu_len);
    return w_end(&w);
}

size_t rfh_encode_antenna_set(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_antenna_set_t *r)
{
    writer_t w;
    int i;
    w_begin(&w, out, cap, RFH_ANTENNA_SET, h);
    if (r == NULL) {
        return 0;
    }
    w_u16(&w, r->emitter_seq);
    w_u8(&w, r->channel);
    w_u8(&w, r->page);
    w_u8(&w, (uint8_t)r->rssi_base_dbm);
    w_u8(&w, r->valid_mask);
    for (i = 0; i < 4; ++i) {
        w_u8(&w, r->antennas[i].ed);
        w_u8(&w, r->antennas[i].lqi);
        w_u16(&w, (uint16_t)r->antennas[i].dt_us);
    }
    return w_end(&w);
}

size_t rfh_encode_status(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_status_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_STATUS, h);
    if (r == NULL) {
        return 0;
    }
    w_u8(&w, r->device_kind);
    w_u8(&w, r->fw_major);
    w_u8(&w, r->fw_minor);
    w_u8(&w, r->fw_patch);
    w_u32(&w, r->uptime_ms);
    w_u16(&w, r->tx_dropped);
    w_u16(&w, r->rx_errors);
    return w_end(&w);
}

size_t rfh_encode_odometry(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_odometry_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_ODOMETRY, h);
    if (r == NULL) {
        return 0;
    }
    w_u32(&w, (uint32_t)r->x_mm);
    w_u32(&w, (uint32_t)r->y_mm);
    w_u32(&w, (uint32_t)r->theta_urad);
    w_u16(&w, (uint16_t)r->v_mm_s);
    w_u16(&w, (uint16_t)r->w_mrad_s);
    w_u8(&w, r->flags);
    return w_end(&w);
}

size_t rfh_encode_velocity_command(uint8_t *out, size_t cap, const rfh_header_t *h,
                                   const rfh_velocity_command_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_VELOCITY_COMMAND, h);
    if (r == NULL) {
        return 0;
    }
    w_u16(&w, (uint16_t)r->v_mm_s);
    w_u16(&w, (uint16_t)r->w_mrad_s);
    w_u16(&w, r->timeout_ms);
    return w_end(&w);
}

size_t rfh_encode_range_scan(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_range_scan_t *r)
{
    writer_t w;
    size_t i;
    w_begin(&w, out, cap, RFH_RANGE_SCAN, h);
    if (r == NULL || (r->count != 0 && r->ranges_mm == NULL)) {
        return 0;
    }
    w_u16(&w, (uint16_t)r->angle_min_mrad);
    w_u16(&w, (uint16_t)r->angle_inc_mrad);
    w_u8(&w, r->count);
    for (i = 0; i < r->count; ++i) {
        w_u16(&w, r->ranges_mm[i]);
    }
    return w_end(&w);
}

/* Whether b[0..len) is well-formed UTF-8 (Unicode 15, table 3-7): no overlong forms, no
 * surrogates, nothing past U+10FFFF -- exactly what the host's decoder accepts. */
int rfh_utf8_valid(const uint8_t *b, size_t len)
{
    size_t i = 0;
    while (i < len) {
        uint8_t c = b[i];
        size_t n, k;
        uint8_t lo = 0x80u, hi = 0xBFu; /* the range of the second byte */
        if (c < 0x80u) {
            ++i;
            continue;
        }
        if (c >= 0xC2u && c <= 0xDFu) {
            n = 1;
        } else if (c >= 0xE0u && c <= 0xEFu) {
            n = 2;
            lo = c == 0xE0u ? 0xA0u : 0x80u;
            hi = c == 0xEDu ? 0x9Fu : 0xBFu;
        } else if (c >= 0xF0u && c <= 0xF4u) {
            n = 3;
            lo = c == 0xF0u ? 0x90u : 0x80u;
            hi = c == 0xF4u ? 0x8Fu : 0xBFu;
        } else {
            return 0;
        }
        if (len - i <= n || b[i + 1] < lo || b[i + 1] > hi) {
            return 0;
        }
        for (k = 2; k <= n; ++k) {
            if ((b[i + k] & 0xC0u) != 0x80u) {
                return 0;
            }
        }
        i += n + 1;
    }
    return 1;
}

size_t rfh_encode_range_scan_v2(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_range_scan_v2_t *r)
{
    writer_t w;
    size_t i;
    w_begin(&w, out, cap, RFH_RANGE_SCAN_V2, h);
    if (r == NULL || (r->count != 0 && r->ranges_mm == NULL)) {
        return 0;
    }
    w_u32(&w, (uint32_t)r->angle_min_urad);
    w_u32(&w, (uint32_t)r->angle_max_urad);
    w_u16(&w, r->range_max_mm);
    w_u8(&w, r->count);
    for (i = 0; i < r->count; ++i) {
        w_u16(&w, r->ranges_mm[i]);
    }
    return w_end(&w);
}

size_t rfh_encode_log_text(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_log_text_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_LOG_TEXT, h);
    if (r == NULL || !rfh_utf8_valid((const uint8_t *)r->text, r->len)) {
        return 0;
    }
    w_bytes(&w, (const uint8_t *)r->text, r->len);
    return w_end(&w);
}

size_t rfh_encode_node_command(uint8_t *out, size_t cap, const rfh_header_t *h, const rfh_node_command_t *r)
{
    writer_t w;
    w_begin(&w, out, cap, RFH_NODE_COMMAND, h);
    if (r == NULL) {
        return 0;
    }
    w_u8(&w, r->command);
    w_bytes(&w, r->args, r->args_len);
    return w_end(&w);
}

/* ---- decoder ------------------------------------------------------------------------------ */

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)get_u16(p) | ((uint32_t)get_u16(p + 2) << 16);
}

void rfh_decoder_init(rfh_decoder_t *dec)
{
    memset(dec, 0, sizeof *dec);
}

static rfh_dec_result_t drop(rfh_decoder_t *dec, rfh_drop_t why)
{
    dec->drop = why;
    dec->drops++;
    return RFH_DEC_DROP;
}

/* The length dec->buf decodes to, or (size_t)-1 when it is no valid COBS encoding. */
static size_t cobs_length(const rfh_decoder_t *dec)
{
    size_t i = 0, n = 0;
    while (i < dec->len) {
        uint8_t code = dec->buf[i++];
        if (code == 0 || i + code - 1u > dec->len) {
            return (size_t)-1;
        }
        i += code - 1u;
        n += code - 1u + (code != 0xFFu && i < dec->len);
    }
    return n;
}

/* Check COBS, then the decoded length (the encoder's limit, RFH_MAX_INNER: checked after COBS,
 * as the host does), decode dec->buf into dec->inner, then check length, CRC and version. */
static rfh_dec_result_t finish_frame(rfh_decoder_t *dec)
{
    size_t i = 0, n = cobs_length(dec), end;
    if (n == (size_t)-1) {
        return drop(dec, RFH_DROP_COBS);
    }
    if (n > RFH_MAX_INNER) {
        return drop(dec, RFH_DROP_OVERSIZE);
    }
    n = 0;
    while (i < dec->len) {
        uint8_t code = dec->buf[i++];
        size_t k;
        for (k = 1; k < code; ++k) {
            dec->inner[n++] = dec->buf[i++];
        }
        if (code != 0xFFu && i < dec->len) {
            dec->inner[n++] = 0;
        }
    }
    if (n < RFH_HEADER_SIZE + RFH_CRC_SIZE) {
        return drop(dec, RFH_DROP_SHORT);
    }
    end = n - RFH_CRC_SIZE;
    if (get_u16(dec->inner + end) != rfh_crc16(dec->inner, end)) {
        return drop(dec, RFH_DROP_CRC);
    }
    if (dec->inner[0] != RFH_VERSION) {
        return drop(dec, RFH_DROP_VERSION);
    }
    dec->inner_len = n;
    dec->type = dec->inner[1];
    dec->header.node_id = dec->inner[2];
    dec->header.seq = get_u16(dec->inner + 3);
    dec->header.t_us = get_u32(dec->inner + 5);
    dec->drop = RFH_DROP_NONE;
    dec->frames++;
    return RFH_DEC_FRAME;
}

rfh_dec_result_t rfh_decoder_feed(rfh_decoder_t *dec, uint8_t byte)
{
    if (byte == 0) {
        size_t had = dec->len;
        int discarding = dec->discarding;
        dec->discarding = 0;
        if (discarding || had == 0) {
            dec->len = 0;
            return RFH_DEC_NONE;
        }
        {
            rfh_dec_result_t res = finish_frame(dec);
            dec->len = 0;
            return res;
        }
    }
    if (dec->discarding) {
        return RFH_DEC_NONE;
    }
    if (dec->len >= RFH_MAX_ENCODED) {
        dec->discarding = 1;
        dec->len = 0;
        return drop(dec, RFH_DROP_OVERSIZE);
    }
    dec->buf[dec->len++] = byte;
    return RFH_DEC_NONE;
}

const uint8_t *rfh_decoder_body(const rfh_decoder_t *dec, size_t *len)
{
    *len = dec->inner_len - RFH_HEADER_SIZE - RFH_CRC_SIZE;
    return dec->inner + RFH_HEADER_SIZE;
}

/* ---- body parsers ------------------------------------------------------------------------- */

int rfh_parse_adv_report(const uint8_t *b, size_t len, rfh_adv_report_t *r)
{
    if (len < 12u || len != 12u + b[11]) {
        return 0;
    }
    memcpy(r->addr, b, 6);
    r->addr_type = b[6];
    r->adv_props = b[7];
    r->rssi_dbm = (int8_t)b[8];
    r->tx_power_dbm = (int8_t)b[9];
    r->channel = b[10];
    r->ad_len = b[11];
    r->ad = b + 12;
    return 1;
}

int rfh_parse_rf_frame(const uint8_t *b, size_t len, rfh_rf_frame_t *r)
{
    if (len < 11u || len != 11u + b[10]) {
        return 0;
    }
    r->antenna = b[0];
    r->channel = b[1];
    r->page = b[2];
    r->trx_ctrl_2 = b[3];
    r->rssi_base_dbm = (int8_t)b[4];
    r->ed = b[5];
    r->lqi = b[6];
    r->rx_status = b[7];
    r->emitter_seq = get_u16(b + 8);
    r->psdu_len = b[10];
    r->psdu = b + 11;
    return 1;
}

int rfh_parse_antenna_set(const uint8_t *b, size_t len, rfh_antenna_set_t *r)
{
    int i;
    if (len != 22u) {
        return 0;
    }
    r->emitter_seq = get_u16(b);
    r->channel = b[2];
    r->page = b[3];
    r->rssi_base_dbm = (int8_t)b[4];
    r->valid_mask = b[5];
    for (i = 0; i < 4; ++i) {
        const uint8_t *a = b + 6 + 4 * i;
        r->antennas[i].ed = a[0];
        r->antennas[i].lqi = a[1];
        r->antennas[i].dt_us = (int16_t)get_u16(a + 2);
    }
    return 1;
}

int rfh_parse_status(const uint8_t *b, size_t len, rfh_status_t *r)
{
    if (len != 12u) {
        return 0;
    }
    r->device_kind = b[0];
    r->fw_major = b[1];
    r->fw_minor = b[2];
    r->fw_patch = b[3];
    r->uptime_ms = get_u32(b + 4);
    r->tx_dropped = get_u16(b + 8);
    r->rx_errors = get_u16(b + 10);
    return 1;
}

int rfh_parse_odometry(const uint8_t *b, size_t len, rfh_odometry_t *r)
{
    if (len != 17u) {
        return 0;
    }
    r->x_mm = (int32_t)get_u32(b);
    r->y_mm = (int32_t)get_u32(b + 4);
    r->theta_urad = (int32_t)get_u32(b + 8);
    r->v_mm_s = (int16_t)get_u16(b + 12);
    r->w_mrad_s = (int16_t)get_u16(b + 14);
    r->flags = b[16];
    return 1;
}

int rfh_parse_velocity_command(const uint8_t *b, size_t len, rfh_velocity_command_t *r)
{
    if (len != 6u) {
        return 0;
    }
    r->v_mm_s = (int16_t)get_u16(b);
    r->w_mrad_s = (int16_t)get_u16(b + 2);
    r->timeout_ms = get_u16(b + 4);
    return 1;
}

int rfh_parse_range_scan(const uint8_t *b, size_t len, rfh_range_scan_t *r, const uint8_t **ranges_le)
{
    if (len < 5u || len != 5u + 2u * b[4]) {
        return 0;
    }
    r->angle_min_mrad = (int16_t)get_u16(b);
    r->angle_inc_mrad = (int16_t)get_u16(b + 2);
    r->count = b[4];
    r->ranges_mm = NULL;
    *ranges_le = b + 5;
    return 1;
}

int rfh_parse_range_scan_v2(const uint8_t *b, size_t len, rfh_range_scan_v2_t *r, const uint8_t **ranges_le)
{
    if (len < 11u || len != 11u + 2u * b[10]) {
        return 0;
    }
    r->angle_min_urad = (int32_t)get_u32(b);
    r->angle_max_urad = (int32_t)get_u32(b + 4);
    r->range_max_mm = get_u16(b + 8);
    r->count = b[10];
    r->ranges_mm = NULL;
    *ranges_le = b + 11;
    return 1;
}

int rfh_parse_log_text(const uint8_t *b, size_t len, rfh_log_text_t *r)
{
    if (!rfh_utf8_valid(b, len)) {
        return 0;
    }
    r->text = (const char *)b;
    r->len = len;
    return 1;
}

int rfh_parse_node_command(const uint8_t *b, size_t len, rfh_node_command_t *r)
{
    if (len < 1u) {
        return 0;
    }
    r->command = b[0];
    r->args = b + 1;
    r->args_len = len - 1u;
    return 1;
}

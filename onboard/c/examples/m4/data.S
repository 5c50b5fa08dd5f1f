/* The weight blob and the calls file, linked into flash (paths given at build time by
 * scripts/c-sil.sh). The blob is 64-byte aligned as in the Rust image; the library reads it in
 * place and needs no alignment. */
    .section .rodata.lt_blob, "a"
    .balign 64
    .global lt_blob
lt_blob:
    .incbin LT_BLOB_PATH
    .global lt_blob_end
lt_blob_end:

    .section .rodata.lt_calls, "a"
    .balign 8
    .global lt_calls
lt_calls:
    .incbin LT_CALLS_PATH
    .global lt_calls_end
lt_calls_end:

//! Integration tests that launch real process networks live in tests/tests.

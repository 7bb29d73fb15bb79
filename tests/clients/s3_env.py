"""The S3 test server the client checks write to: ``CHUNKSTORE_TEST_S3`` (which ``.ci/run``
starts, SeaweedFS with keys ``key``/``secret``), as the tool's environment and as the
storage options Python readers take."""

import os

CREDENTIALS = {
    "AWS_ALLOW_HTTP": "true",
    "AWS_ACCESS_KEY_ID": "key",
    "AWS_SECRET_ACCESS_KEY": "secret",
    "AWS_REGION": "us-east-1",
}


def s3_endpoint(what):
    """The endpoint, or None (said, outside CI) when no server is named: CI must check
    `what` against one."""
    endpoint = os.environ.get("CHUNKSTORE_TEST_S3")
    if not endpoint:
        assert not os.environ.get("CI"), f"CI checks {what}: CHUNKSTORE_TEST_S3 must name an S3 server"
        print(f"{what}: skipped (CHUNKSTORE_TEST_S3 names no S3 server)")
    return endpoint


def s3_options(endpoint):
    """The settings that reach the server, as ``storage_options`` (deltalake, Polars)."""
    return dict(CREDENTIALS, AWS_ENDPOINT_URL=endpoint)


def tool_env(endpoint):
    """The tool's environment with the server's settings."""
    return dict(os.environ, **s3_options(endpoint))


def s3_client(endpoint):
    """A boto3 S3 client of the server (to upload, and to list what a write left)."""
    import boto3

    return boto3.client(
        "s3",
        endpoint_url=endpoint,
        aws_access_key_id=CREDENTIALS["AWS_ACCESS_KEY_ID"],
        aws_secret_access_key=CREDENTIALS["AWS_SECRET_ACCESS_KEY"],
        region_name=CREDENTIALS["AWS_REGION"],
    )

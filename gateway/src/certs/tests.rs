//! `rove keys`: a fleet's files, issued, listed and revoked.

use super::*;
use openssl::x509::X509Crl;

/// A path for a fleet's directory (not made yet), and the temp dir that holds it (removed when
/// the test drops it).
fn scratch() -> (tempfile::TempDir, PathBuf) {
    let tmp = tempfile::tempdir().expect("temp dir");
    let dir = tmp.path().join("fleet");
    (tmp, dir)
}

#[test]
fn a_revoked_device_is_listed_in_a_signed_list_copied_to_every_device() {
    let (_tmp, dir) = scratch();
    init(&dir, "test fleet", 0).expect("init");
    for id in [11, 12] {
        add(&dir, id, Lifetime::DEVICE, false).expect("add");
    }
    let empty =
        X509Crl::from_pem(&std::fs::read(dir.join(CRL_FILE)).expect("list")).expect("a PEM CRL");
    assert!(empty.get_revoked().is_none_or(|r| r.is_empty()));
    let done = revoke(&dir, 12).expect("revoke");
    assert_eq!(done.listed, 1);
    assert_eq!(done.copied.len(), 2);
    let ca = X509::from_pem(&std::fs::read(dir.join("ca.cert.pem")).expect("ca")).expect("pem");
    for device in ["11", "12"] {
        let pem = std::fs::read(dir.join(device).join(CRL_FILE)).expect("copied");
        let crl = X509Crl::from_pem(&pem).expect("a PEM CRL");
        assert!(crl.verify(&ca.public_key().expect("key")).expect("verify"));
    }
    let listed: Vec<(i64, bool)> = (list(&dir).expect("list").into_iter())
        .map(|d| (d.id, d.revoked))
        .collect();
    assert_eq!(listed, [(11, false), (12, true)]);
    assert!(revoke(&dir, 12).is_err(), "revoked once");
    assert!(revoke(&dir, 13).is_err(), "no such device");
    // Renewed: a new certificate the list does not name; the old entry stays.
    add(&dir, 12, Lifetime::DEVICE, true).expect("renew");
    assert!(!list(&dir).expect("list")[1].revoked, "renewed");
    revoke(&dir, 11).expect("revoke 11");
    let crl =
        X509Crl::from_pem(&std::fs::read(dir.join(CRL_FILE)).expect("list")).expect("a PEM CRL");
    assert_eq!(crl.get_revoked().map_or(0, |r| r.len()), 2);
}

#[test]
fn a_fleet_issues_device_certificates_that_verify_against_its_ca() {
    let (_tmp, dir) = scratch();
    init(&dir, "test fleet", 0).expect("init");
    let out = add(&dir, 11, Lifetime::DEVICE, false).expect("add");
    let ca = X509::from_pem(&std::fs::read(dir.join("ca.cert.pem")).expect("ca")).expect("pem");
    let cert = X509::from_pem(&std::fs::read(out.join("cert.pem")).expect("cert")).expect("pem");
    assert!(cert.verify(&ca.public_key().expect("key")).expect("verify"));
    let cn = cert
        .subject_name()
        .entries_by_nid(Nid::COMMONNAME)
        .next()
        .expect("CN");
    assert_eq!(cn.data().to_string().expect("utf-8"), "rove-11");
    let mode = std::os::unix::fs::PermissionsExt::mode(
        &std::fs::metadata(out.join("key.pem"))
            .expect("key")
            .permissions(),
    );
    assert_eq!(mode & 0o777, 0o600);
    let signed = std::fs::read_to_string(out.join("permissions.p7s")).expect("p7s");
    assert!(signed.contains("multipart/signed") && signed.contains("CN=rove-11,O=test fleet"));
    assert!(
        add(&dir, 11, Lifetime::DEVICE, false).is_err(),
        "a device is issued once"
    );
    let fleet = check_device_dir(&out, 11, false).expect("complete");
    assert_eq!(fleet.fleet(), "test fleet");
    let e = check_device_dir(&out, 12, false).expect_err("another's");
    assert!(format!("{e:#}").contains("not device 12's"), "{e:#}");
    assert!(init(&dir, "again", 0).is_err(), "a fleet is created once");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_web_certificate_verifies_against_the_fleet_ca_and_serves_tls() {
    let (_tmp, dir) = scratch();
    init(&dir, "test fleet", 0).expect("init");
    let hosts = ["rover-base.local".to_string(), "192.168.1.20".to_string()];
    let out = web(&dir, &hosts, Lifetime::DEVICE).expect("issued");
    let pem = |p: &Path| std::fs::read(p).expect("read");
    let ca = X509::from_pem(&pem(&dir.join("ca.cert.pem"))).expect("ca");
    let cert = X509::from_pem(&pem(&out.join("cert.pem"))).expect("cert");
    assert!(cert.verify(&ca.public_key().expect("key")).expect("verify"));
    let names: Vec<String> = (cert.subject_alt_names().expect("SAN").iter())
        .map(|n| {
            n.dnsname().map(str::to_string).unwrap_or_else(|| {
                let ip = n.ipaddress().unwrap_or_default();
                ip.iter().map(u8::to_string).collect::<Vec<_>>().join(".")
            })
        })
        .collect();
    assert_eq!(names, hosts);
    let files = (out.join("cert.pem"), out.join("key.pem"));
    let listen = "127.0.0.1:8443".parse().expect("addr");
    let served = crate::web::tls::identity(Some(&files), listen).expect("rustls takes it");
    assert!(served.origin.starts_with("loaded"), "{}", served.origin);
    assert!(
        web(&dir, &hosts, Lifetime::DEVICE).is_err(),
        "never overwritten"
    );
    assert!(web(&dir, &[], Lifetime::DEVICE).is_err());
}

#[test]
fn the_guid_start_names_one_device() {
    let fleet = FleetIdentity {
        fleet: "test fleet".into(),
        starts: Default::default(),
    };
    let a = fleet.guid_start(11).expect("hash");
    let b = fleet.guid_start(12).expect("hash");
    assert_ne!(a, b);
    assert_eq!(a[0] & 0x80, 0x80, "the first bit is set");
    let mut prefix = [0u8; 16];
    prefix[4..10].copy_from_slice(&a);
    let participant = ParticipantId(u128::from_be_bytes(prefix));
    assert_eq!(fleet.speaks_for(11, participant), Certified::Device);
    assert_eq!(fleet.speaks_for(12, participant), Certified::No);
}

#[test]
fn a_secured_sites_proxies_speak_for_their_ids_at_their_level_only() {
    let (_tmp, dir) = scratch();
    init(&dir, "test fleet", 0).expect("init");
    let home = rove_core::site::SiteName::new("home").expect("name");
    let out = site_proxies(&dir, &home, &[100, 12], Level::Stationary, Lifetime::DEVICE)
        .expect("proxies");
    assert!(
        site_proxies(&dir, &home, &[12], Level::Remote, Lifetime::DEVICE).is_err(),
        "never overwritten"
    );
    site_proxies(&dir, &home, &[13], Level::Remote, Lifetime::DEVICE).expect("one more");
    let identity = SiteIdentity::load(&out, &home).expect("loads");
    let other = rove_core::site::SiteName::new("lab").expect("name");
    assert!(SiteIdentity::load(&out, &other).is_err(), "not lab's");
    assert_eq!(identity.proxy(12).map(|p| p.1), Some(Level::Stationary));
    assert_eq!(identity.proxy(13).map(|p| p.1), Some(Level::Remote));
    assert_eq!(identity.proxy(11), None);
    // Each proxy directory is a device directory for its id, under rustdds's file names.
    check_device_dir(&out.join("proxies/12"), 12, false).expect("a device directory");
    // The GUID a participant under the proxy certificate of 12 gets: a proxy of 12 at its
    // level, nobody's device.
    let cert = X509::from_pem(&std::fs::read(out.join("proxies/12/cert.pem")).expect("read"))
        .expect("pem");
    let start = guid_start_for(cert.subject_name()).expect("hash");
    let mut prefix = [0u8; 16];
    prefix[4..10].copy_from_slice(&start);
    let participant = ParticipantId(u128::from_be_bytes(prefix));
    let fleet = &identity.fleet;
    assert_eq!(
        fleet.speaks_for(12, participant),
        Certified::Proxy(Level::Stationary)
    );
    assert_eq!(fleet.speaks_for(100, participant), Certified::No);
    // The bridge's own certificate speaks for no id.
    let own = X509::from_pem(&std::fs::read(out.join("dds/cert.pem")).expect("read")).expect("pem");
    let start = guid_start_for(own.subject_name()).expect("hash");
    prefix[4..10].copy_from_slice(&start);
    let bridge = ParticipantId(u128::from_be_bytes(prefix));
    for id in [12, 13, 100, 0] {
        assert_eq!(fleet.speaks_for(id, bridge), Certified::No);
    }
}

#[test]
fn a_revoked_site_is_named_in_a_signed_list_and_its_identities_in_the_crl() {
    let (_tmp, dir) = scratch();
    init(&dir, "test fleet", 0).expect("init");
    add(&dir, 11, Lifetime::DEVICE, false).expect("add");
    let home = rove_core::site::SiteName::new("home").expect("name");
    let lab = rove_core::site::SiteName::new("lab").expect("name");
    site(&dir, &home, &[], Lifetime::DEVICE).expect("site");
    site_proxies(&dir, &home, &[100], Level::Remote, Lifetime::DEVICE).expect("proxies");
    site(&dir, &lab, &[], Lifetime::DEVICE).expect("site");
    assert!(revoke_site(&dir, &lab).is_ok());
    let done = revoke_site(&dir, &home).expect("revoke");
    assert!(revoke_site(&dir, &home).is_err(), "once");
    assert_eq!(
        done.listed, 4,
        "lab's link, home's link, its own and its proxy's identity"
    );
    let ca = dir.join("ca.cert.pem");
    for copy in [dir.clone(), dir.join("site-home"), dir.join("site-lab")] {
        let names = revoked_sites(&ca, &copy.join(REVOKED_SITES_FILE)).expect("verifies");
        assert_eq!(names.into_iter().collect::<Vec<_>>(), ["home", "lab"]);
    }
    // Every identity directory has the new list, which names the proxy's certificate.
    let crl = X509Crl::from_pem(&std::fs::read(dir.join("11").join(CRL_FILE)).expect("read"))
        .expect("crl");
    let proxy =
        X509::from_pem(&std::fs::read(dir.join("site-home/proxies/100/cert.pem")).expect("read"))
            .expect("pem");
    assert!(!matches!(
        crl.get_by_cert(&proxy),
        openssl::x509::CrlStatus::NotRevoked
    ));
    let copy = std::fs::read(dir.join("site-home/proxies/100").join(CRL_FILE)).expect("copied");
    assert_eq!(copy, std::fs::read(dir.join(CRL_FILE)).expect("read"));
    // An edited list, or one signed by another fleet's CA, is refused.
    let file = dir.join(REVOKED_SITES_FILE);
    let text = String::from_utf8(std::fs::read(&file).expect("read")).expect("text");
    let edited = dir.join("edited.p7s");
    std::fs::write(&edited, text.replacen("home", "hume", 1)).expect("write");
    assert!(revoked_sites(&ca, &edited).is_err(), "edited");
    let (_stranger_tmp, stranger) = scratch();
    init(&stranger, "strangers", 0).expect("init");
    assert!(
        revoked_sites(&stranger.join("ca.cert.pem"), &file).is_err(),
        "another CA"
    );
}

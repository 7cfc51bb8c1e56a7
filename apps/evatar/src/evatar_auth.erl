%% @doc Internal. Who may join a pairing as which entity, pure: credentials
%% stored as salted PBKDF2-HMAC-SHA256 hashes and compared in constant time,
%% per-entity identities (a credential, a client certificate's SHA-256
%% fingerprint, or both), and the ids reserved for EVATAR itself.
%%
%% A pairing's options name either the shared role credentials
%% (`agent_credential', `avatar_credential'), or a list of `identities', or
%% both. When an EntityID is listed, only its own identity joins or resumes
%% it; an unlisted EntityID joins with the role credential only when the
%% pairing says `unlisted_ids => role_credential' (or has no identities at
%% all). docs/protocol.md section 7.3 is the full rule.
%%
%% The hash runs in the joining client's process ({@link verify/2}), never
%% in the pairing's: a pairing only hands out the stored hash
%% ({@link requirement/3}) and receives a verdict, so the plain credential
%% is never in its state, its replicated events or its logs.
-module(evatar_auth).

-export([hash/1, hash/2, normalise/1, requirement/3, verify/2, check_id/2, reserved/1,
         log_id/1, escaped_size/1, default_iterations/0]).

-export_type([hashed/0, identity/0, requirement/0, auth/0, peer_cert/0, verdict/0]).

-type hashed() :: {pbkdf2_sha256, Iterations :: pos_integer(), Salt :: binary(),
                   Hash :: binary()}.
%% A device's identity, as normalised: `cert_sha256' is lower-case hex.
-type identity() :: #{entity := binary(),
                      role := evatar:role(),
                      credential => hashed(),
                      cert_sha256 => binary()}.
%% What a join of one EntityID in one role must present.
-type requirement() :: #{credential => hashed(), cert_sha256 => binary()} | refuse.
%% The verified client certificate of a TLS connection, if any.
-type peer_cert() :: #{sha256 := binary(), cn => binary()}.
%% What a joining client presents: a credential, or the auth-data map
%% (a credential and the connection's verified certificate).
-type auth() :: binary() | #{credential := binary(), peer_cert => peer_cert() | undefined}.
-type verdict() :: authenticated | bad_credential.

%% PBKDF2-HMAC-SHA256, 1,000 iterations, 16-byte salt, 32-byte hash: about
%% 0.3 ms of CPU per handshake, spent in the connection's process. Not more:
%% crypto:pbkdf2_hmac/5 is a plain NIF in OTP 25, which holds its scheduler
%% for the whole hash (3.7 ms at 10,000 iterations), so a burst of
%% handshakes would delay every other process of the node
%% (docs/protocol.md section 7).
-define(ITERATIONS, 1000).
-define(SALT_BYTES, 16).
-define(HASH_BYTES, 32).
-define(MAX_ITERATIONS, 10000000).
-define(LOG_ID_BYTES, 64).

%% @doc The iterations {@link hash/1} uses.
-spec default_iterations() -> pos_integer().
default_iterations() -> ?ITERATIONS.

%% @doc A credential's stored form, with a fresh random salt and the
%% default iteration count.
-spec hash(binary()) -> hashed().
hash(Plain) -> hash(Plain, ?ITERATIONS).

%% @doc A credential's stored form with `Iterations' iterations.
-spec hash(binary(), pos_integer()) -> hashed().
hash(Plain, Iterations) when is_binary(Plain), is_integer(Iterations), Iterations > 0,
                             Iterations =< ?MAX_ITERATIONS ->
    Salt = crypto:strong_rand_bytes(?SALT_BYTES),
    {pbkdf2_sha256, Iterations, Salt, derive(Plain, Iterations, Salt)}.

derive(Plain, Iterations, Salt) ->
    crypto:pbkdf2_hmac(sha256, Plain, Salt, Iterations, ?HASH_BYTES).

%% @doc Checks and normalises the identity options of a pairing: plain
%% credentials become hashes (a hash is kept as it is, so the result
%% normalises to itself), fingerprints become lower-case hex without
%% separators. Options other than the identity ones pass through.
-spec normalise(map()) -> {ok, map()} | {error, {bad_option, term()}}.
normalise(Opts) ->
    try
        Opts1 = maps:map(fun(K, V) when K =:= agent_credential; K =:= avatar_credential ->
                                 stored(K, V);
                            (identities, V) ->
                                identities(V);
                            (unlisted_ids, V) when V =:= refuse; V =:= role_credential ->
                                V;
                            (unlisted_ids, V) ->
                                throw({bad_option, {unlisted_ids, V}});
                            (_, V) ->
                                V
                         end, Opts),
        %% Without identities both role credentials are needed, as before.
        case [K || K <- [agent_credential, avatar_credential], not maps:is_key(K, Opts1)] of
            Missing when Missing =:= []; is_map_key(identities, Opts1) ->
                {ok, Opts1};
            Missing ->
                {error, {bad_option, {missing, Missing}}}
        end
    catch
        throw:{bad_option, _} = Bad -> {error, Bad}
    end.

stored(_K, Plain) when is_binary(Plain) ->
    hash(Plain);
stored(_K, {pbkdf2_sha256, I, Salt, Hash} = H)
  when is_integer(I), I > 0, I =< ?MAX_ITERATIONS, is_binary(Salt), is_binary(Hash),
       byte_size(Hash) =:= ?HASH_BYTES ->
    H;
stored(K, V) ->
    throw({bad_option, {K, V}}).

identities(List) when is_list(List) ->
    Ids = [identity(I) || I <- List],
    Entities = [E || #{entity := E} <- Ids],
    case length(lists:usort(Entities)) =:= length(Entities) of
        true -> Ids;
        false -> throw({bad_option, {identities, duplicate_entity}})
    end;
identities(V) ->
    throw({bad_option, {identities, V}}).

identity(#{entity := E, role := R} = I)
  when is_binary(E), byte_size(E) > 0, (R =:= agent orelse R =:= avatar) ->
    case maps:keys(maps:without([entity, role, credential, cert_sha256], I)) of
        [] -> ok;
        Extra -> throw({bad_option, {identity, E, {unknown_keys, Extra}}})
    end,
    I1 = case I of
             #{credential := C} -> I#{credential := stored({identity, E}, C)};
             #{} -> I
         end,
    case I1 of
        #{cert_sha256 := F} -> I1#{cert_sha256 := fingerprint(E, F)};
        #{credential := _} -> I1;
        #{} -> throw({bad_option, {identity, E, no_credential_or_certificate}})
    end;
identity(I) ->
    throw({bad_option, {identity, I}}).

%% A SHA-256 fingerprint as hex, with or without colons, in either case, or
%% the whole line `openssl x509 -noout -fingerprint -sha256' prints
%% (`sha256 Fingerprint=AB:CD:...'): the text after `=' counts.
fingerprint(E, F) when is_binary(F) ->
    Hex = hex(string:trim(lists:last(binary:split(F, <<"=">>)))),
    case byte_size(Hex) =:= 64 andalso
        lists:all(fun(C) -> (C >= $0 andalso C =< $9) orelse (C >= $a andalso C =< $f) end,
                  binary_to_list(Hex)) of
        true -> Hex;
        false -> throw({bad_option, {identity, E, {cert_sha256, F}}})
    end;
fingerprint(E, F) ->
    throw({bad_option, {identity, E, {cert_sha256, F}}}).

hex(F) ->
    string:lowercase(binary:replace(F, <<":">>, <<>>, [global])).

%% @doc What a join of `EntityId' in `Role' must present under the
%% (normalised) options: a listed EntityID its own identity (and its role);
%% an unlisted one the role credential when the pairing allows it.
-spec requirement(evatar:role(), binary(), map()) -> requirement().
requirement(Role, EntityId, Config) ->
    Identities = maps:get(identities, Config, []),
    case [I || #{entity := E} = I <- Identities, E =:= EntityId] of
        [#{role := Role} = I] ->
            maps:with([credential, cert_sha256], I);
        [_OtherRole] ->
            refuse;
        [] when Identities =:= [] ->
            role_requirement(Role, Config);
        [] ->
            case maps:get(unlisted_ids, Config, refuse) of
                role_credential -> role_requirement(Role, Config);
                refuse -> refuse
            end
    end.

role_requirement(Role, Config) ->
    Key = case Role of
              agent -> agent_credential;
              avatar -> avatar_credential
          end,
    case Config of
        #{Key := Hashed} -> #{credential => Hashed};
        #{} -> refuse
    end.

%% @doc Checks what a client presents against a requirement: every part
%% named must match. The hashes are compared with crypto:hash_equals/2.
-spec verify(requirement(), auth()) -> verdict().
verify(refuse, _Auth) ->
    bad_credential;
verify(Requirement, Credential) when is_binary(Credential) ->
    verify(Requirement, #{credential => Credential});
verify(Requirement, #{credential := Credential} = Auth) when is_binary(Credential) ->
    CredOk = case Requirement of
                 #{credential := {pbkdf2_sha256, I, Salt, Hash}} ->
                     crypto:hash_equals(derive(Credential, I, Salt), Hash);
                 #{} ->
                     true
             end,
    CertOk = case {Requirement, maps:get(peer_cert, Auth, undefined)} of
                 {#{cert_sha256 := Want}, #{sha256 := Got}} when is_binary(Got) ->
                     Hex = hex(Got),
                     byte_size(Hex) =:= byte_size(Want) andalso crypto:hash_equals(Hex, Want);
                 {#{cert_sha256 := _}, _} ->
                     false;
                 {#{}, _} ->
                     true
             end,
    case CredOk andalso CertOk of
        true -> authenticated;
        false -> bad_credential
    end;
verify(_Requirement, _Auth) ->
    bad_credential.

%% @doc Checks an entity or component id: at most `MaxLength' bytes as the
%% Binding report writes it (XML-escaped), and not one a person could take
%% for EVATAR's own ({@link reserved/1}).
-spec check_id(binary(), pos_integer()) -> ok | {error, id_too_long | reserved_id}.
check_id(Id, MaxLength) ->
    case escaped_size(Id) > MaxLength of
        true -> {error, id_too_long};
        false ->
            case reserved(Id) of
                true -> {error, reserved_id};
                false -> ok
            end
    end.

%% @doc The bytes `Value' takes as the text of an XML element.
-spec escaped_size(binary()) -> non_neg_integer().
escaped_size(Value) ->
    iolist_size(bil:escape_text(Value)).

%% @doc True for an id that reads `EVATAR' once ASCII case and every
%% character that is not an ASCII letter or digit are ignored (`evatar',
%% ` EVATAR ', `E.V.A.T.A.R', `evatar-'): the sender of EVATAR's own
%% signals. EVATAR-made signals also carry `Origin' `EVATAR'
%% (docs/protocol.md), which no entity can send.
-spec reserved(binary()) -> boolean().
reserved(Id) ->
    << <<(C bor 32)>> || <<C>> <= Id, (C >= $A andalso C =< $Z) orelse
                                           (C >= $a andalso C =< $z) orelse
                                           (C >= $0 andalso C =< $9) >> =:= <<"evatar">>.

%% @doc An id as a log shows it: whole up to 64 bytes, else its first 64
%% bytes and its size, so a refused 60 KB id does not write 60 KB of log.
-spec log_id(term()) -> term().
log_id(Id) when is_binary(Id), byte_size(Id) > ?LOG_ID_BYTES ->
    Head = binary:part(Id, 0, ?LOG_ID_BYTES),
    <<Head/binary, "... (", (integer_to_binary(byte_size(Id)))/binary, " bytes)">>;
log_id(Id) ->
    Id.
